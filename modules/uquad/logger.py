"""Logging processes, one per data type (seed 002 §1.2.1: slow storage never delays the control loop).

Each class reads one routed input (the manifest points it at the uquad module's slot) and appends every datum
as a JSON line to ``<LOG_DIR>/<robot>_<data type>.jsonl`` (LOG_DIR from the .conf, relative to the working
directory, or the ``dir`` param). Run as ``python -m modules.uquad.logger`` with the ``kind`` param (imu_raw,
state, control) choosing the class; the manifest's ``class`` key names the same class.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import IO, Any, ClassVar

import msgspec

from bbcs import EXIT_CONFIG, Control, InputSlot, Kind, Module, Safety
from modules.uquad.config import load_config
from modules.uquad.params import load_logger_params, logger_param_errors
from modules.uquad.structs import ImuRaw, MotorCommandLog, UquadState


class LoggerControl(msgspec.Struct, frozen=True, kw_only=True):
    slot_entrada_datos: int = -1


ROUTE = Control(LoggerControl, {"slot_entrada_datos": "datos"})


class _Logger(Module):
    data_type: ClassVar[str] = ""
    flush_every: ClassVar[int] = 100

    @classmethod
    def param_errors(cls, params: dict[str, str]) -> list[tuple[str, str]]:
        """Every problem of the logger's manifest ``params`` (``cromat launch --check``, with file:line)."""
        return logger_param_errors(params, cls.data_type)

    def __init__(self, context: Any) -> None:
        super().__init__(context)
        self.log_params = load_logger_params(context.params, self.data_type)  # ParamError: exit 78, not restarted

    def on_start(self) -> None:
        folder = self.log_params.dir or (load_config(self.context.conf).values.LOG_DIR
                                     if self.context.conf else "runs")
        path = Path(folder)
        path.mkdir(parents=True, exist_ok=True)
        self.path = path / f"{self.robot}_{self.data_type}.jsonl"
        self.file: IO[bytes] = open(self.path, "ab")  # noqa: SIM115 - closed in on_stop
        self.written = 0
        self.encoder = msgspec.json.Encoder()

    def on_datos(self, value: Any) -> None:
        self.file.write(self.encoder.encode(value) + b"\n")
        self.written += 1
        if self.written % self.flush_every == 0:
            self.file.flush()

    def on_stop(self) -> None:
        if hasattr(self, "file"):
            self.file.close()


class ImuRawLogger(_Logger):
    name: ClassVar[str] = "log_imu_raw"
    data_type = "imu_raw"
    control = ROUTE
    slots = (InputSlot("datos", ImuRaw, kind=Kind.STREAM, queue=4096),)


class StateLogger(_Logger):
    name: ClassVar[str] = "log_state"
    data_type = "state"
    control = ROUTE
    slots = (InputSlot("datos", UquadState, safety=Safety.SAFE, queue=4096),)


class ControlLogger(_Logger):
    name: ClassVar[str] = "log_control"
    data_type = "control"
    control = ROUTE
    slots = (InputSlot("datos", MotorCommandLog, kind=Kind.STREAM, queue=4096),)


LOGGERS = {cls.data_type: cls for cls in (ImuRawLogger, StateLogger, ControlLogger)}


def main(argv: list[str] | None = None) -> int:
    from bbcs.context import load_context

    context = load_context(argv, "python -m modules.uquad.logger", "log")
    kind = context.params.get("kind", "")
    if kind not in LOGGERS:
        print(f"configuration error: param kind must be one of {sorted(LOGGERS)}, got {kind!r}", file=sys.stderr)
        return EXIT_CONFIG  # not restarted: the manifest must change
    return LOGGERS[kind].main(argv)


if __name__ == "__main__":
    sys.exit(main())
