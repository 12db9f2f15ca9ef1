"""The consumer process of ``cromat demo``."""

from examples.bus_demo import Consumer

if __name__ == "__main__":
    raise SystemExit(Consumer.main())
