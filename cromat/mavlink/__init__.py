"""``cromat mavlink``: a MAVLink gateway over the GRI (docs/mavlink.md).

Every robot a ground station sees on the bus becomes a MAVLink vehicle (its own system id) for QGroundControl,
MAVSDK and pymavlink. The gateway is a ground-station process like ``cromat gcs``: every command becomes a GRI task
request (the RAL's admission, the Module Manager's one task book, the router's access control, the link-loss
failsafe all apply unchanged); it adds no path of its own to the modules.

One job per module: ``dialect`` (pymavlink's MAVLink 2 codec and signing), ``endpoints`` (UDP, TCP server, serial),
``params`` (.conf values as MAVLink parameters), ``telemetry`` (GRI state → messages, rates), ``statustext`` (GRI
events and errors → STATUSTEXT), ``commands`` (COMMAND_LONG/INT → GRI requests), ``mission`` (the mission transfer
protocol, a state machine), ``plan`` (mission items → a path, progress), ``fence`` (fence items → world-model
zones), ``vehicle`` (one robot's MAVLink side), ``gateway`` (the process), ``cli`` (its command line).
"""
