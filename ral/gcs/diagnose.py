"""Why a ground station could not get through: one of a few named causes instead of a bare timeout.

Zenoh reports a refused link as "unable to connect" whatever the cause. When that happens the GCS repeats the
connection step by step with the same files: a TCP connect (``router unreachable``), then a TLS handshake with
the station's CA, certificate and key (``TLS refused: no certificate / unknown CA / expired / not yet valid /
router name mismatch``), reading the
certificate's dates and the router's TLS alert. A request that got no answer from a robot that is visibly
alive was dropped by the router's access policy (``denied by policy``).
"""

from __future__ import annotations

import socket
import ssl
import subprocess
from datetime import UTC, datetime

from bbcs import SessionConfig

UNREACHABLE = "router unreachable"
NO_CERTIFICATE = "TLS refused: no certificate"
UNKNOWN_CA = "TLS refused: unknown CA"
EXPIRED = "TLS refused: expired"
NOT_YET_VALID = "TLS refused: not yet valid"
NAME_MISMATCH = "TLS refused: router name mismatch"
DENIED = "denied by policy"


def _endpoint(endpoint: str) -> tuple[str, str, int]:
    proto, _, rest = endpoint.partition("/")
    hostport = rest.split("#", 1)[0]
    host, _, port = hostport.rpartition(":")
    return proto, host.strip("[]"), int(port)


def _cert_dates(cert: str) -> tuple[datetime, datetime] | None:
    proc = subprocess.run(["openssl", "x509", "-noout", "-startdate", "-enddate", "-in", cert],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        return None
    dates = dict(line.split("=", 1) for line in proc.stdout.splitlines() if "=" in line)
    fmt = "%b %d %H:%M:%S %Y %Z"
    start, end = (datetime.strptime(" ".join(dates[k].split()), fmt).replace(tzinfo=UTC)
                  for k in ("notBefore", "notAfter"))
    return start, end


def diagnose_connect(cfg: SessionConfig, timeout_s: float = 3.0, now: datetime | None = None) -> str:
    """The cause, as one line starting with one of the names above, of a failed connection to the router."""
    if not cfg.connect:
        return f"{UNREACHABLE}: no endpoint to connect to"
    proto, host, port = _endpoint(cfg.connect[0])
    try:
        raw = socket.create_connection((host, port), timeout=timeout_s)
    except OSError as exc:
        return f"{UNREACHABLE}: {host}:{port}: {exc.strerror or exc}"
    with raw:
        if proto != "tls":
            return f"{UNREACHABLE}: {host}:{port} accepts connections but refused this {proto}/ link (a tls/ router?)"
        tls = cfg.tls
        if tls is None or not tls.cert or not tls.key:
            return f"{NO_CERTIFICATE}: the router requires this station's certificate (--cert, --key)"
        dates = _cert_dates(tls.cert)
        now = now or datetime.now(UTC)
        if dates is not None and now > dates[1]:
            return f"{EXPIRED}: this station's certificate {tls.cert} expired on {dates[1]:%Y-%m-%d %H:%M} UTC"
        if dates is not None and now < dates[0]:
            return (f"{NOT_YET_VALID}: this station's certificate {tls.cert} is not valid before "
                    f"{dates[0]:%Y-%m-%d %H:%M} UTC (is this computer's clock right?)")
        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        ctx.check_hostname = tls.verify_name
        try:
            ctx.load_verify_locations(tls.root_ca)
            ctx.load_cert_chain(tls.cert, tls.key)
        except (OSError, ssl.SSLError) as exc:
            return f"{NO_CERTIFICATE}: cannot load this station's TLS files: {exc}"
        try:
            with ctx.wrap_socket(raw, server_hostname=host) as conn:
                conn.settimeout(min(timeout_s, 1.0))
                try:  # TLS 1.3: the server judges the client's certificate after the handshake, then alerts
                    conn.recv(1)
                except TimeoutError:
                    pass
        except ssl.SSLCertVerificationError as exc:
            if "mismatch" in (exc.verify_message or ""):
                return (f"{NAME_MISMATCH}: the router's certificate does not name {host} ({exc.verify_message}); "
                        f"connect by a name it carries, or re-issue it with --router-host {host}")
            return f"{UNKNOWN_CA}: the router's certificate is not signed by {tls.root_ca} ({exc.verify_message})"
        except ssl.SSLError as exc:
            reason = (exc.reason or str(exc)).upper()
            if "UNKNOWN_CA" in reason or "BAD_CERTIFICATE" in reason or "DECRYPT" in reason:
                return f"{UNKNOWN_CA}: the router does not trust this station's certificate {tls.cert} ({exc.reason})"
            if "EXPIRED" in reason:
                return f"{EXPIRED}: the router says this station's certificate has expired ({exc.reason})"
            if "CERTIFICATE_REQUIRED" in reason:
                return f"{NO_CERTIFICATE}: the router requires this station's certificate ({exc.reason})"
            return f"TLS refused: {exc.reason or exc}"
        except OSError as exc:
            return f"{UNREACHABLE}: {host}:{port} closed the TLS link: {exc}"
    return f"TLS accepted by {host}:{port}; the Zenoh session itself failed (see the error)"


def explain_no_reply(robot: str, robot_visible: bool, what: str) -> str:
    """Why a request got no answer: the robot is alive but did not answer (the policy) or is not there."""
    if robot_visible:
        return (f"{DENIED}: robot {robot!r} is up but {what} got no answer: the router's access policy drops it "
                f"for this station's identity (this station's identity may not submit it)")
    return f"no answer from robot {robot!r} to {what}: the robot is not running or unreachable"
