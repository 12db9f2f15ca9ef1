"""Simulators at the far end of real transports (pty, TCP on 127.0.0.1), always stopped after the test."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TypeVar

import pytest

from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.sim import LdmrsSimulator, MTiGSimulator, World

Sim = TypeVar("Sim", MTiGSimulator, LdmrsSimulator)


@pytest.fixture
def make_world() -> Callable[..., World]:
    def make(scale: float = 10.0, **kw) -> World:
        return World(clock=ScaledClock(scale), **kw)

    return make


def _started(make: Callable[..., Sim]) -> Iterator[Callable[..., Sim]]:
    """Yield a starter of ``make``'s simulators; every one it started is stopped, also on failure."""
    started: list[Sim] = []

    def start(*args, **kwargs) -> Sim:
        sim = make(*args, **kwargs)
        started.append(sim)
        return sim.start()

    try:
        yield start
    finally:
        for sim in started:
            sim.stop()


@pytest.fixture
def start_mtig() -> Iterator[Callable[[World], MTiGSimulator]]:
    yield from _started(MTiGSimulator)


@pytest.fixture
def start_ldmrs() -> Iterator[Callable[..., LdmrsSimulator]]:
    """``start_ldmrs(world, options=None)``: a started ``LdmrsSimulator``."""
    yield from _started(LdmrsSimulator)
