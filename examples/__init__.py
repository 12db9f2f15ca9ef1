"""Short runnable programs, one concept each."""
