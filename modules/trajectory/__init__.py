"""Trajectory generator: survey lawnmowers, orbits and smoothed waypoint lists as DATOS paths (seed 004)."""
