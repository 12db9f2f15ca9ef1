"""The flight-safety monitor (issue 31): every breach of the flight invariants, with its evidence."""
