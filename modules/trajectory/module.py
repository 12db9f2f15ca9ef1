"""The trajectory generator as a bus module (seed 004: one of the writers the Module Manager routes the path
follower's DATOS to).

Slots (``cromat/<robot>/trajectory/...``):
- ``request`` — safe stream input, ``bbcs.contracts.trajectory.TrajectoryRequest``: one survey, orbit or
  smooth request;
- ``survey``, ``orbit``, ``smooth`` — safe stream outputs, the path follower's ``DatosSegCam``: each plan on
  the output of its kind, so a task routes ``path_follower.datos`` to the slot of the kind it flies;
- ``status`` — safe stream output, ``TrajectoryStatus``: every request answered (accepted with the path's
  length, spacing and lines, or refused with the reason; a refused request publishes no path, nor does an
  accepted ``check_only`` one: the RAL's question before it starts the task).

Params (manifest ``params``, strings): ``speed``, ``max_bank_deg`` (the turn radius v²/(g·tan φ)),
``ground_altitude`` (datum of ``altura``), ``line_extension``, ``arc_step_deg``, ``max_points``.
"""

from __future__ import annotations

from typing import ClassVar

from bbcs import InputSlot, Kind, Module, ModuleContext, OutputSlot, ParamServer
from bbcs.contracts.path_follower import DatosSegCam
from bbcs.contracts.trajectory import TrajectoryRequest, TrajectoryStatus
from modules.trajectory.generator import Limits, plan


class TrajectoryModule(Module):
    name: ClassVar[str] = "trajectory"
    slots = (
        InputSlot("request", TrajectoryRequest, kind=Kind.STREAM),
        OutputSlot("survey", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("orbit", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("smooth", DatosSegCam, kind=Kind.STREAM),
        OutputSlot("status", TrajectoryStatus, kind=Kind.STREAM),
    )
    param_errors = staticmethod(Limits.param_errors)
    """The trajectory's check of its manifest params (``cromat launch --check``, with file:line)."""
    params_type = Limits
    runtime_params = frozenset(Limits.__struct_fields__)
    """Every limit is settable at run time (``cromat param set``): each request is planned with the limits in
    force when it is handled, and a path already sent is not changed."""

    def __init__(self, context: ModuleContext) -> None:
        super().__init__(context)
        self.limits = Limits.from_params(dict(context.params))  # ParamError: exit 78, not restarted

    def on_start(self) -> None:
        self.param_server = ParamServer(self, lambda: self.limits, self._set_limits, self.runtime_params)

    def _set_limits(self, limits: Limits) -> None:
        self.limits = limits

    def on_request(self, req: TrajectoryRequest) -> None:
        try:
            result = plan(req, self.limits)
        except ValueError as exc:
            kind = next((k for k in ("survey", "orbit", "smooth") if getattr(req, k) is not None), "")
            self.log.warning("request %d refused: %s", req.request_id, exc)
            self.publish("status", TrajectoryStatus(request_id=req.request_id, kind=kind,  # type: ignore[arg-type]
                                                    accepted=False, reason=str(exc)))
            return
        if not req.check_only:
            self.publish(result.kind, result.path)
        self.publish("status", TrajectoryStatus(
            request_id=req.request_id, kind=result.kind, accepted=True, reason="",  # type: ignore[arg-type]
            n_points=result.path.n_points, path_length_m=result.length_m, line_spacing_m=result.spacing_m,
            lines=result.lines))
