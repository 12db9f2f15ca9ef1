"""``cromat bus list`` counts a key's publishers and subscribers (issue 34 item 4: tools and ground stations were
invisible), from the router's admin space when the manifest turns it on, and says when it is off."""

from __future__ import annotations

import json
import subprocess
import threading

import pytest

from bbcs.session import local_client, open_session
from bbcs.testing import Processes, free_port, start_router, wait_port
from cromat.tools import bus_cli
from cromat.tools.attendance import Declarations, parse_entry

KEY = "cromat/r1/m/a"


def test_counting_rules() -> None:
    zid = "fd5ce102145ddfe1b047b8af54ecd411"
    entry = parse_entry(f"@/{zid}/router/subscriber/cromat/r1/*/*",
                        json.dumps({"routers": [zid], "peers": [], "clients": ["c1"]}).encode())
    assert entry == ("subscriber", "cromat/r1/*/*", {"c1"})  # the router itself relays, it is no subscriber
    assert parse_entry(f"@/{zid}/router/linkstate/north", b"graph {}") is None
    d = Declarations(subscribers={"cromat/r1/*/*": {"c1"}, KEY: {"c1", "c2"}, "cromat/r2/**": {"c3"}},
                     publishers={KEY: {"p"}})
    assert d.count(KEY) == (1, 2) and d.count("cromat/r1/m/b") == (0, 1)


def publish_until(stop: threading.Event, port: int) -> threading.Thread:
    def run() -> None:
        session = open_session(local_client(port))
        pub = session.declare_publisher(KEY)
        while not stop.wait(0.1):
            pub.put(b"\x80")  # an empty msgpack map
        pub.undeclare()
        session.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("admin", [True, False])
def test_list_counts_publishers_and_subscribers(admin: bool, capsys: pytest.CaptureFixture[str]) -> None:
    procs = Processes()
    stop = threading.Event()
    sessions = []
    thread = None
    try:
        if admin:
            port = free_port()
            procs.start(["-m", "bbcs.router", "--listen", f"tcp/127.0.0.1:{port}", "--admin-space"],
                        stdout=subprocess.DEVNULL)
            wait_port(port)
        else:
            port = start_router(procs)
        heard = threading.Event()
        for sel in (KEY, "cromat/r1/*/*", "cromat/r2/x/y"):  # a ground station, a recorder, someone else's
            session = open_session(local_client(port))
            sessions.append(session)
            session.declare_subscriber(sel, lambda _s: heard.set() if _s.key_expr == KEY else None)
        thread = publish_until(stop, port)
        # a sample the router carried: the publisher's declaration, sent before it on its link, is in the router
        # (a clean-clone run at load 50 listed the key with 0 publishers: the tool asked before it had arrived)
        assert heard.wait(20), "the publisher's samples never reached the subscribers"
        argv = ["--connect", f"tcp/127.0.0.1:{port}", "--timeout", "2", "list", "--robot", "r1", "--window", "1.5"]
        assert bus_cli.main([*argv, "--json"]) == 0
        row = {r["key"]: r for r in map(json.loads, capsys.readouterr().out.splitlines())}[KEY]
        assert (row["publishers"], row["subscribers"]) == ((1, 2) if admin else (None, None))
        assert bus_cli.main(argv) == 0
        text = capsys.readouterr().out
        line = next(x for x in text.splitlines() if x.startswith(KEY))
        assert line.split()[-1] == ("1/2" if admin else "-")
        assert ("counts need the router's admin space" in text) is not admin
    finally:
        stop.set()
        for session in sessions:
            session.close()
        procs.stop_all()
        if thread is not None:
            thread.join(5)
