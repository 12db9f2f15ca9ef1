"""``python -m stuck_module``: a module whose input handler never returns (stuck), for the watchdog test."""

import threading

from mm_modules import ProbeMsg

from bbcs.module import Module
from bbcs.slots import InputSlot, Kind


class Stuck(Module):
    name = "stuck"
    slots = (InputSlot("datos", ProbeMsg, kind=Kind.STREAM, peer="src_a"),)

    def on_datos(self, msg: ProbeMsg) -> None:
        threading.Event().wait()  # never returns: the loop, and with it the heartbeat, stops


if __name__ == "__main__":
    raise SystemExit(Stuck.main())
