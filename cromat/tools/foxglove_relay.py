"""One public WebSocket port for every Foxglove client: the open protocol's ``foxglove.websocket.v1`` and the
SDK's ``foxglove.sdk.v1`` / ``foxglove.sdk.v1.1``.

foxglove-sdk (0.30) serves only its own ``foxglove.sdk.*`` subprotocols and answers a client offering
``foxglove.websocket.v1`` (``@foxglove/ws-protocol``, Lichtblick, the ROS bridges' clients) with HTTP 400. Its
``foxglove.sdk.v1`` messages are those of ``foxglove.websocket.v1`` (the same ``serverInfo``, ``advertise`` with
the schema inline, ``subscribe``, binary message data with opcode 1); ``v1.1`` differs (schemas advertised apart).
So the SDK's server listens on an internal loopback port and this relay, on the public port, accepts any of the
three and relays every frame both ways over a connection to the SDK's server in the matching dialect:
``foxglove.websocket.v1`` over ``foxglove.sdk.v1``, the SDK's own subprotocols as themselves. A
``foxglove.websocket.v1`` client is sent only what that protocol defines (other server operations are dropped),
so an SDK newer than its dialect cannot break it.
"""

from __future__ import annotations

import json
import threading
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect as ws_connect
from websockets.sync.server import Server, ServerConnection, serve

OPEN_PROTOCOL = "foxglove.websocket.v1"
SDK_PROTOCOLS = ("foxglove.sdk.v1.1", "foxglove.sdk.v1")
SUBPROTOCOLS = (OPEN_PROTOCOL, *SDK_PROTOCOLS)
UPSTREAM = {OPEN_PROTOCOL: "foxglove.sdk.v1", "foxglove.sdk.v1": "foxglove.sdk.v1",
            "foxglove.sdk.v1.1": "foxglove.sdk.v1.1"}
"""Client's subprotocol → the dialect spoken to the SDK's server for it."""

OPEN_TEXT_OPS = frozenset({"serverInfo", "status", "removeStatus", "advertise", "unadvertise", "parameterValues",
                           "advertiseServices", "unadvertiseServices", "connectionGraphUpdate",
                           "serviceCallFailure"})
OPEN_BINARY_OPS = frozenset({1, 2, 3, 4})
"""What ``foxglove.websocket.v1`` servers send: JSON operations, and binary message data, time, service call
response, fetch asset response."""


def open_protocol_allows(frame: str | bytes) -> bool:
    """Whether a server frame is part of ``foxglove.websocket.v1`` (a client of it rejects anything else)."""
    if isinstance(frame, bytes | bytearray | memoryview):
        return len(frame) > 0 and frame[0] in OPEN_BINARY_OPS
    try:
        doc = json.loads(frame)
    except ValueError:
        return False
    return isinstance(doc, dict) and doc.get("op") in OPEN_TEXT_OPS


class FoxgloveRelay:
    """The public port: each client connection relayed to the SDK's server at ``127.0.0.1:upstream_port``."""

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        self.upstream = f"ws://127.0.0.1:{upstream_port}"
        self.dropped = 0
        """Server frames not sent to a ``foxglove.websocket.v1`` client (not in that protocol)."""
        self._lock = threading.Lock()
        self._server: Server = serve(self._client, host, port, subprotocols=list(SUBPROTOCOLS),
                                     process_request=self._refuse_without_subprotocol, compression=None,
                                     max_size=None)
        self.port: int = self._server.socket.getsockname()[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name="foxglove.relay", daemon=True)
        self._thread.start()

    @staticmethod
    def _refuse_without_subprotocol(_conn: ServerConnection, request: Any) -> Any:
        offered = {p.strip() for p in request.headers.get("Sec-WebSocket-Protocol", "").split(",")}
        if offered & set(SUBPROTOCOLS):
            return None
        return _conn.respond(400, f"offer one of the subprotocols {', '.join(SUBPROTOCOLS)}\n")

    def _client(self, client: ServerConnection) -> None:
        proto = client.subprotocol or OPEN_PROTOCOL
        try:
            upstream = ws_connect(self.upstream, subprotocols=[UPSTREAM[proto]], compression=None, max_size=None,
                                  open_timeout=5)
        except (OSError, TimeoutError, ConnectionClosed) as exc:
            client.close(1011, f"the bridge's Foxglove server is not answering: {exc}"[:120])
            return
        only_open = proto == OPEN_PROTOCOL
        down = threading.Thread(target=self._pump, args=(upstream, client, only_open), name="foxglove.relay.down",
                                daemon=True)
        down.start()
        self._pump(client, upstream, False)
        upstream.close()
        client.close()
        down.join(5)

    def _pump(self, source: Any, sink: Any, only_open: bool) -> None:
        try:
            for frame in source:
                if only_open and not open_protocol_allows(frame):
                    with self._lock:
                        self.dropped += 1
                    continue
                sink.send(frame)
        except ConnectionClosed:
            pass
        finally:
            sink.close()

    def stop(self) -> None:
        self._server.shutdown()
        self._thread.join(5)
