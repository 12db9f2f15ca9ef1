"""bbcs: the bus every cromat module stands on (CROMAT's BBCS rebuilt on Zenoh).

What a module, a tool or an example needs is importable from here (``from bbcs import Module, InputSlot``);
the submodules hold the rest: ``keys`` the key-expression scheme, ``contracts`` the message types, ``geodesy``
the one Earth model, ``wire`` the payload encoding.
"""

from bbcs.conf import ConfDocument, ConfError, ConfGroup, load_conf
from bbcs.context import ModuleContext
from bbcs.errors import EXIT_CONFIG, BbcsError, BusErrorCode, InvalidNameError, RouteError, SessionError, SlotError
from bbcs.module import Control, Heartbeat, Module
from bbcs.params import ParamServer, load_params, raise_first, struct_param_errors
from bbcs.routing import IGNORE, RouteAck, SlotRef, SlotTable
from bbcs.session import SessionConfig, TlsConfig, local_client, open_session
from bbcs.slots import Direction, InputSlot, Kind, OutputSlot, Publisher, Safety, SlotSpec
from bbcs.stop_signals import forward_stop_signals

__all__ = [
    "BbcsError", "BusErrorCode", "ConfDocument", "ConfError", "ConfGroup", "Control", "Direction", "EXIT_CONFIG",
    "Heartbeat", "IGNORE", "InputSlot", "InvalidNameError", "Kind", "Module", "ModuleContext", "OutputSlot",
    "ParamServer", "Publisher", "RouteAck", "RouteError", "Safety", "SessionConfig", "SessionError", "SlotError",
    "SlotRef", "SlotSpec", "SlotTable", "TlsConfig", "forward_stop_signals", "load_conf", "load_params",
    "local_client", "open_session", "raise_first", "struct_param_errors",
]
