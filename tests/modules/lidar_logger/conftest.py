"""Simulators at the far end of real transports (pty, TCP on 127.0.0.1), always stopped after the test."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from modules.lidar_logger.clock import ScaledClock
from modules.lidar_logger.sim import LdmrsOptions, LdmrsSimulator, MTiGSimulator, World


@pytest.fixture
def make_world() -> Callable[..., World]:
    def make(scale: float = 10.0, **kw) -> World:
        return World(clock=ScaledClock(scale), **kw)

    return make


@pytest.fixture
def start_mtig() -> Iterator[Callable[[World], MTiGSimulator]]:
    started: list[MTiGSimulator] = []

    def start(world: World) -> MTiGSimulator:
        sim = MTiGSimulator(world)
        started.append(sim)
        return sim.start()

    try:
        yield start
    finally:
        for sim in started:
            sim.stop()


@pytest.fixture
def start_ldmrs() -> Iterator[Callable[..., LdmrsSimulator]]:
    started: list[LdmrsSimulator] = []

    def start(world: World, options: LdmrsOptions | None = None) -> LdmrsSimulator:
        sim = LdmrsSimulator(world, options)
        started.append(sim)
        return sim.start()

    try:
        yield start
    finally:
        for sim in started:
            sim.stop()
