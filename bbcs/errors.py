"""The bus's error tree, and the error codes every module shares.

```
BbcsError
 ├── ConfError            a .conf file is malformed (file, line, column)   [bbcs.conf]
 ├── InvalidNameError     a robot/module/slot name cannot be used in a key expression
 ├── SessionError         the Zenoh session cannot be opened (router unreachable, bad TLS files)
 ├── SlotError            a slot declaration or a slot use is wrong (type, direction, unknown slot)
 └── RouteError           an input cannot be routed to the requested slot number
```
"""

from __future__ import annotations

from enum import IntEnum

EXIT_CONFIG = 78
"""Exit status of a module whose configuration (robot .conf, params) is invalid: ``os.EX_CONFIG``. The Module
Manager never restarts a module that exits with it (restarting cannot fix a file)."""


class BbcsError(Exception):
    """Base class of every error the bus library raises."""


class InvalidNameError(BbcsError, ValueError):
    """A robot, module or slot name would break the key-expression scheme."""


class SessionError(BbcsError):
    """A Zenoh session could not be opened with the given configuration."""


class SlotError(BbcsError):
    """A slot is declared or used in a way its declaration does not allow."""


class RouteError(BbcsError):
    """A route names a slot number that is missing or carries another struct type (``code``: BusErrorCode)."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class BusErrorCode(IntEnum):
    """Error codes the bus itself puts on a module's ERROR slot (1–99; modules use 100 and up).

    The seed's rule holds for all of them: the datum that caused the code is never acted on.
    """

    OUT_OF_RANGE = 1
    """A datum decoded but a field is outside the range its struct declares."""
    MALFORMED = 2
    """A datum could not be decoded as the slot's struct (wrong type, truncated, not msgpack)."""
    ROUTE_UNKNOWN_SLOT = 3
    """CONTROL_ENTRADA names a slot number missing from the robot's slot table; old routes kept."""
    ROUTE_TYPE_MISMATCH = 4
    """CONTROL_ENTRADA routes an input to a slot of another struct type; old routes kept."""
    HANDLER_FAILED = 5
    """The module's own handler raised while processing a valid datum (a bug; see the log)."""
    LIMIT_EXCEEDED = 6
    """A datum exceeds a limit known only at run time (e.g. MAX_SPEED from the robot .conf)."""
    KEY_REFUSED = 7
    """Data put on a key expression with wildcards reached an input only its exact key may feed (CONTROL_ENTRADA,
    the DSP's command inputs): dropped, counted, reported at most once a second (bbcs/ingress.py)."""
