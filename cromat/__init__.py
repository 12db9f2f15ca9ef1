"""cromat: a publish/subscribe module bus for robots (CROMAT style) on Zenoh."""

__version__ = "0.1.0"
