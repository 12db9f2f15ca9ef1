"""Tools on top of the bus: introspection (``cromat bus``), MCAP record and replay, the Foxglove bridge.

They work against any robot router, learning what is on the bus from what the bus itself serves: liveliness
tokens, each module's ``@schema`` answer, and the manager's slot table.
"""
