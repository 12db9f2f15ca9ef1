"""bbcs: the bus every cromat module stands on (CROMAT's BBCS rebuilt on Zenoh).

``session`` opens Zenoh sessions, ``keys`` owns the key-expression scheme, ``slots`` the slot kinds and their
QoS, ``module`` the Module base, ``routing`` the slot table, ``conf`` the robot .conf parser.
"""

from bbcs.context import ModuleContext
from bbcs.errors import BbcsError, BusErrorCode, InvalidNameError, RouteError, SessionError, SlotError
from bbcs.module import Control, Module
from bbcs.routing import IGNORE, RouteAck, SlotRef, SlotTable
from bbcs.session import SessionConfig, TlsConfig, open_session
from bbcs.slots import Direction, InputSlot, Kind, OutputSlot, Safety, SlotSpec

__all__ = [
    "IGNORE", "BbcsError", "BusErrorCode", "Control", "Direction", "InputSlot", "InvalidNameError", "Kind",
    "Module", "ModuleContext", "OutputSlot", "RouteAck", "RouteError", "Safety", "SessionConfig", "SessionError",
    "SlotError", "SlotRef", "SlotSpec", "SlotTable", "TlsConfig", "open_session",
]
