"""The DSP serial protocol (codec, framing, link over pyserial), its start-up sequence, and a DSP simulator.

docs/dsp_protocol.md is the wire contract; ``modules.dsp.sim`` is the far end used by every test.
"""
