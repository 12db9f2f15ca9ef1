"""``free_port`` hands out listening ports outside the ephemeral range, and still one when that range is full."""

from __future__ import annotations

import socket

import pytest

from bbcs import net


def test_a_free_port_is_outside_the_ephemeral_range_and_binds() -> None:
    ephemeral = net._ephemeral()
    for _ in range(20):
        port = net.free_port()
        assert port not in ephemeral
        assert port in net.LISTEN_PORTS
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))


def test_when_every_listen_port_is_taken_the_os_picks_one(monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        busy = taken.getsockname()[1]
        monkeypatch.setattr(net, "LISTEN_PORTS", range(busy, busy + 1))
        monkeypatch.setattr(net, "_ephemeral", lambda: range(0))
        port = net.free_port()
        assert port != busy
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))
