"""Pan & tilt module (seed 004 §5.3.2.2)."""
