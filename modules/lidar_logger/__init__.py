"""Lidar logger: MTi-G pose source + SICK/ibeo LD-MRS scanner, synchronised, one log per flight
(seed 000, ch. 4).

Layers, each in its own module: wire protocols (``xbus``, ``mtdata``, ``ldmrs_proto``, ``ldmrs_scan``), device
drivers (``mtig``, ``ldmrs``), the acquisition loop (``buffer``, ``logger``), log formats (``textlog``,
``binlog``, ``logdata``), post-processing (``geodesy``, ``georef``, ``ply``) and byte-exact simulators
(``sim``).
"""
