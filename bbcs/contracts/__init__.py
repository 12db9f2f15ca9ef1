"""The contracts between processes, in one place at the bottom of the stack.

Every struct that crosses a process boundary and is shared by more than one package lives here; ``ral``,
``module_manager`` and ``modules/*`` import these and never each other (``tests/test_layering.py`` enforces it).

| module | what |
| --- | --- |
| :mod:`bbcs.contracts.geo` | latitude, longitude, altitude, angle types with their ranges; ``GeoPoint``, ``Attitude`` |
| :mod:`bbcs.contracts.robot` | ``RobotTelemetry``: what every robot reports about its body |
| :mod:`bbcs.contracts.errors` | ``ErrorReport``: the one shape of every module's ERROR slot |
| :mod:`bbcs.contracts.pan_tilt` | the pan & tilt module's slot structs (seed 004 §5.3.2.2) |
| :mod:`bbcs.contracts.path_follower` | the path follower's slot structs (seed 004 §5.3.2.3) |
| :mod:`bbcs.contracts.tasks` | typed task parameters, the tagged union a task carries from GRI to the manager |
| :mod:`bbcs.contracts.gri` | the GRI: what ground stations and the RAL exchange |
| :mod:`bbcs.contracts.mri` | the MRI: requests to a robot's Module Manager and its robot state |
| :mod:`bbcs.contracts.trajectory` | requests to the trajectory generator and its answers |
| :mod:`bbcs.contracts.lidar` | ``LidarScan``: one lidar scan on the bus, points as packed buffers |
"""
