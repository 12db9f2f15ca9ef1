"""Telemetry module (seed 004 §5.3.2.1): the DSP's telemetry as the generic robot telemetry, always on."""
