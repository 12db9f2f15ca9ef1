"""Path follower / bridge to the low-level controller (seed 004 §5.3.2.3)."""
