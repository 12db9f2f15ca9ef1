"""The uQuad simulator: rigid body + motors + sensors (``quad``), and the far ends of the IMU, GPS and ESC
links on 127.0.0.1 TCP ports or a pty (``server``). ``python -m modules.uquad.sim --help``."""
