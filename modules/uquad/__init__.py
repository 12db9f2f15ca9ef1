"""The uQuad quadrotor of seed 002 as a second robot kind: IMU, GPS, estimator, controller, motor driver.

Sub-modules each do one job; docs/uquad.md describes the protocols, the .conf keys and the processes.
"""
