"""Byte-exact simulators of the MTi-G (pty) and the LD-MRS (TCP), flying over a known synthetic terrain.

In-process::

    world = World(clock=ScaledClock(10))
    with MTiGSimulator(world) as imu, LdmrsSimulator(world) as lidar:
        ...  # point the logger at imu.port and 127.0.0.1:lidar.port

As a process: ``python -m modules.lidar_logger.sim --time-scale 1`` prints the pty path and TCP port as one
JSON line and serves until SIGINT/SIGTERM.
"""

from modules.lidar_logger.sim.ldmrs_sim import LdmrsDevice, LdmrsOptions, LdmrsSimulator
from modules.lidar_logger.sim.mtig_sim import MTiGDevice, MTiGSimulator
from modules.lidar_logger.sim.world import SEED_UTC_START, Flight, Terrain, World

__all__ = ["SEED_UTC_START", "Flight", "LdmrsDevice", "LdmrsOptions", "LdmrsSimulator", "MTiGDevice",
           "MTiGSimulator", "Terrain", "World"]
