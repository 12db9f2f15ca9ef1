"""Short runnable programs, one concept each. Each has ``main(conf: SessionConfig) -> int`` and runs as
``python -m examples.NAME [--connect ENDPOINT]`` against a router (``cromat router`` or a launched robot).

| program | concept |
| --- | --- |
| ``typed_slot`` | a slot carries a msgspec struct as msgpack; decoding it is validating it |
| ``module_errors`` | a bbcs Module refuses an out-of-range datum and says so on its ERROR slot |
| ``plain_client`` | a robot read and commanded with only ``zenoh`` and ``msgpack`` (docs/interop.md) |
"""
