"""``cromat certs DIR``: a CA and certificates for a robot router, ground stations and modules (openssl CLI).

Three folders, so that no key ends up where it does not belong (docs/security.md, threat model):

* the **CA folder** (``--ca``, default ``DIR-ca``): ``ca.key`` and ``ca.pem``. The operator's; it never goes to
  the robot. ``--init-ca`` only creates it;
* the **robot folder** (``DIR``): ``ca.pem`` and one certificate and key per robot-side identity (router,
  manager, RAL, each module). No CA key and no ground-station key: a robot that is taken cannot mint
  identities or pose as a ground station. A CA key found there is refused;
* the **ground folder** (``--ground``, default ``DIR-ground``): ``ca.pem`` and each ground station's pair.

Each certificate's common name is the identity the router's access policy knows it by (``gcs``, ``ral``,
``manager``, a module's instance name); the router's is ``router-<robot>`` when the robot is known (its identity
on the fleet mesh, docs/fleet.md), and ``--hub NAME`` issues a hub router's pair instead (with ``--acl``, its
config: :func:`bbcs.acl.hub_config`). The router's certificate carries the host names clients connect to
(default ``localhost`` and ``127.0.0.1``). An existing CA is reused, so new identities can be added later.
With ``--acl FILE`` it also writes the robot router's Zenoh config (mTLS + access policy, see
:mod:`bbcs.acl`) pointing at the robot folder. Keys are written mode 0600 and must never be committed.

``--revoke NAME`` (a ground station's identity in the ground folder, or a certificate file) puts that certificate
on the fleet CA's revocation list (CRL, signed by the CA key, :func:`revoke`) and writes the list as ``crl.pem``
in the CA folder (the running list), the robot folder (where the launch tells the RAL to read it) and the ground
folder: a secured robot then adopts nothing that certificate signs (bbcs/signing.py). Copy ``crl.pem`` to every
robot's folder.

The openssl commands are listed in docs/security.md. (Certificates are made with the openssl command-line tool;
the ``cryptography`` package signs and checks fleet tasks and zone edits, bbcs/signing.py, and builds the CRL.)
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import secrets
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature, UnsupportedAlgorithm
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec

from bbcs import acl, keys

CA = "ca"
CRL = "crl.pem"
REVOKED_NAMES = "revoked.txt"
"""Beside ``crl.pem``: the common names of the revoked certificates, one a line. Zenoh's TLS has no CRL setting and
its policy knows identities by CN only, so a robot's router denies these names everything (bbcs/acl.py ``revoked``)
and a revoked name is never issued again: the station is re-issued under a new name."""


def revoked_names(folder: Path) -> list[str]:
    """The names in ``folder``'s :data:`REVOKED_NAMES` (none when it has no such file)."""
    path = folder / REVOKED_NAMES
    if not path.exists():
        return []
    return [line.strip() for line in path.read_text().splitlines() if line.strip()]
CRL_DAYS = 365
"""The list's ``nextUpdate``: robots do not refuse a list older than this (a robot off the network must not stop
obeying its stations because the operator's list went stale); informational."""
DEFAULT_HOSTS = ("localhost", "127.0.0.1")


class CertError(RuntimeError):
    pass


def _openssl(*args: str) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise CertError("the openssl command is not installed (needed by cromat certs); see docs/security.md")
    proc = subprocess.run([exe, *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise CertError(f"openssl {args[0]} failed: {proc.stderr.strip()}")


def _new_key(path: Path) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path))
    os.chmod(path, 0o600)


def make_ca(directory: Path, name: str = "cromat-ca", days: int = 3650) -> tuple[Path, Path]:
    """Create ``ca.key``/``ca.pem`` unless they exist; returns their paths."""
    key, pem = directory / f"{CA}.key", directory / f"{CA}.pem"
    if key.exists() and pem.exists():
        return key, pem
    _new_key(key)
    _openssl(
        "req",
        "-x509",
        "-new",
        "-key",
        str(key),
        "-sha256",
        "-days",
        str(days),
        "-subj",
        f"/CN={name}",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign,cRLSign",
        "-out",
        str(pem),
    )
    return key, pem


def _san(hosts: list[str]) -> str:
    parts = []
    for host in hosts:
        try:
            ipaddress.ip_address(host)
            parts.append(f"IP:{host}")
        except ValueError:
            parts.append(f"DNS:{host}")
    return ",".join(parts)


def make_leaf(
    directory: Path, name: str, hosts: list[str] | None = None, days: int = 825, ca_dir: Path | None = None,
    cn: str | None = None,
) -> tuple[Path, Path]:
    """``NAME.key``/``NAME.pem`` in ``directory``, signed by the CA in ``ca_dir`` (default ``directory``),
    CN=``cn`` (default NAME), server+client use; ``directory`` also gets the CA's certificate (never its key)."""
    ca_dir = ca_dir or directory
    ca_key, ca_pem = ca_dir / f"{CA}.key", ca_dir / f"{CA}.pem"
    if not ca_key.exists():
        raise CertError(f"{ca_dir}: no CA (ca.key); create one first (cromat certs --init-ca --ca {ca_dir})")
    directory.mkdir(parents=True, exist_ok=True)
    if ca_dir != directory and (not (directory / f"{CA}.pem").exists()
                                or (directory / f"{CA}.pem").read_bytes() != ca_pem.read_bytes()):
        shutil.copyfile(ca_pem, directory / f"{CA}.pem")
    key, pem = directory / f"{name}.key", directory / f"{name}.pem"
    _new_key(key)
    with tempfile.TemporaryDirectory() as tmp:
        csr, ext = Path(tmp) / "req.csr", Path(tmp) / "ext.cnf"
        ext.write_text(
            "basicConstraints=critical,CA:FALSE\n"
            "keyUsage=critical,digitalSignature,keyEncipherment\n"
            "extendedKeyUsage=serverAuth,clientAuth\n"
            f"subjectAltName={_san(hosts or [name])}\n"
        )
        _openssl("req", "-new", "-key", str(key), "-subj", f"/CN={cn or name}", "-out", str(csr))
        _openssl(
            "x509",
            "-req",
            "-in",
            str(csr),
            "-CA",
            str(ca_pem),
            "-CAkey",
            str(ca_key),
            "-set_serial",
            f"0x{secrets.token_hex(16)}",
            "-days",
            str(days),
            "-sha256",
            "-extfile",
            str(ext),
            "-out",
            str(pem),
        )
    return key, pem


def revoke(ca_dir: Path, cert_pem: Path, copies: list[Path], now: dt.datetime | None = None) -> Path:
    """Add ``cert_pem`` to the CRL of the CA in ``ca_dir`` (kept there as ``crl.pem``, with every certificate
    revoked before), signed by the CA's key, and write a copy as ``crl.pem`` in each folder of ``copies``.
    Returns the CA folder's list. A certificate the CA did not issue raises :class:`CertError`."""
    try:
        ca_cert = x509.load_pem_x509_certificate((ca_dir / f"{CA}.pem").read_bytes())
        ca_key = serialization.load_pem_private_key((ca_dir / f"{CA}.key").read_bytes(), password=None)
    except (OSError, ValueError) as exc:
        raise CertError(f"{ca_dir}: cannot read the CA (ca.pem, ca.key): {exc}") from exc
    if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
        raise CertError(f"{ca_dir / 'ca.key'}: not an EC key (cromat certs makes EC P-256 CAs)")
    try:
        cert = x509.load_pem_x509_certificate(cert_pem.read_bytes())
    except (OSError, ValueError) as exc:
        raise CertError(f"cannot read the certificate to revoke {cert_pem}: {exc}") from exc
    try:
        cert.verify_directly_issued_by(ca_cert)
    except (ValueError, TypeError, InvalidSignature, UnsupportedAlgorithm) as exc:
        raise CertError(f"{cert_pem} was not issued by the CA in {ca_dir}: nothing to revoke there") from exc
    now = now or dt.datetime.now(dt.UTC)
    held = ca_dir / CRL
    builder = (x509.CertificateRevocationListBuilder().issuer_name(ca_cert.subject).last_update(now)
               .next_update(now + dt.timedelta(days=CRL_DAYS)))
    serials = set()
    if held.exists():
        try:
            previous = x509.load_pem_x509_crl(held.read_bytes())
        except ValueError as exc:
            raise CertError(f"{held}: unreadable revocation list ({exc}); move it away to start a new one") from exc
        if not previous.is_signature_valid(ca_cert.public_key()):  # type: ignore[arg-type]
            raise CertError(f"{held}: revocation list not signed by this CA; move it away to start a new one")
        for entry in previous:
            builder = builder.add_revoked_certificate(entry)
            serials.add(entry.serial_number)
    if cert.serial_number not in serials:
        builder = builder.add_revoked_certificate(
            x509.RevokedCertificateBuilder().serial_number(cert.serial_number).revocation_date(now).build())
    data = builder.sign(ca_key, hashes.SHA256()).public_bytes(serialization.Encoding.PEM)
    names = "".join(f"{n}\n" for n in dict.fromkeys([*revoked_names(ca_dir), *_names_of(cert)]))
    for folder in [ca_dir, *copies]:
        folder.mkdir(parents=True, exist_ok=True)
        for target, content in ((REVOKED_NAMES, names.encode()), (CRL, data)):
            tmp = folder / f".{target}.tmp"
            tmp.write_bytes(content)
            tmp.replace(folder / target)  # whole or not at all: a RAL or a launch may read it at any moment
    return held


def _names_of(cert: x509.Certificate) -> list[str]:
    return [str(a.value) for a in cert.subject.get_attributes_for_oid(x509.oid.NameOID.COMMON_NAME)]


def _revoked_file(name: str, ground: Path) -> Path:
    """``--revoke`` takes a certificate file, or an identity whose certificate is in the ground folder."""
    path = Path(name)
    if path.suffix == ".pem" and path.exists():
        return path
    keys.validate_name(name, "identity to revoke")
    return ground / f"{name}.pem"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cromat certs", description="Create a CA and TLS certificates for cromat."
    )
    p.add_argument(
        "dir",
        nargs="?",
        help="output folder (created; an existing CA in it is reused); with --manifest default: its bus.tls.pki",
    )
    p.add_argument(
        "--manifest",
        metavar="TOML",
        help="make exactly the certificates this launch manifest's [bus.tls] needs (router, manager, its GCS "
        "identities, one per module); --robot comes from it",
    )
    p.add_argument("--ca", metavar="DIR", help="the operator's CA folder (ca.key, ca.pem; created if missing; "
                   "never copy it to the robot); default: DIR-ca next to the robot folder")
    p.add_argument("--ground", metavar="DIR", help="where ground-station certificates and keys go (default: "
                   "DIR-ground next to the robot folder); never the robot folder")
    p.add_argument("--init-ca", action="store_true", help="only create the CA in --ca (the operator's first step)")
    p.add_argument("--ca-name", default="cromat-ca", help="common name of a new CA")
    p.add_argument(
        "--router-host",
        action="append",
        metavar="HOST",
        help="host name or IP the router is reached at (repeatable; default localhost, 127.0.0.1)",
    )
    p.add_argument("--gcs", action="append", metavar="NAME", help="ground-station identity (default: gcs)")
    p.add_argument(
        "--module",
        action="append",
        metavar="NAME",
        help="module identity, its instance name (default: module)",
    )
    p.add_argument(
        "--modules",
        metavar="A,B,...",
        help="module identities as one comma-separated list (adds to --module)",
    )
    p.add_argument("--no-local", action="store_true", help="do not create the ral and manager identities")
    p.add_argument("--days", type=int, default=825)
    p.add_argument("--acl", metavar="FILE", help="also write the robot router's Zenoh config (mTLS + ACL)")
    p.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="router TLS endpoint for --acl (default tls/0.0.0.0:7447)",
    )
    p.add_argument("--robot", default="*", help="robot name the --acl policy is for (default: any); also names the "
                   "router's certificate router-ROBOT, its identity on the fleet mesh")
    p.add_argument("--hub", metavar="NAME", help="instead: a hub (ground) router's pair NAME.pem/NAME.key in DIR "
                   "(its hosts: --router-host); with --acl, the hub's Zenoh config (mTLS + its policy, --robots)")
    p.add_argument("--robots", metavar="A,B,...", help="with --hub --acl: the robots whose routers link to the hub")
    p.add_argument("--revoke", action="append", metavar="NAME|PEM", help="instead: revoke a ground station "
                   "(its certificate NAME.pem in the ground folder, or a certificate file): the CA's revocation list "
                   "crl.pem, written to the CA, robot and ground folders (repeatable)")
    return p


def _hub(args: argparse.Namespace) -> int:
    """``--hub NAME``: the hub router's certificate (CN NAME) in DIR and, with ``--acl``, its config."""
    if not args.dir or not args.ca:
        print("cromat certs: --hub needs the hub's folder DIR and the fleet's CA folder --ca", file=sys.stderr)
        return 2
    out = Path(args.dir)
    robots = [r.strip() for r in (args.robots or "").split(",") if r.strip()]
    try:
        keys.validate_name(args.hub, "hub identity")
        if (out / f"{CA}.key").exists():
            raise CertError(f"{out / 'ca.key'}: a CA key in the hub's folder; keep it in the operator's CA folder")
        if Path(args.ca).resolve() == out.resolve():
            raise CertError("the CA folder must not be the hub's folder")
        make_ca(Path(args.ca), args.ca_name)
        make_leaf(out, args.hub, args.router_host or list(DEFAULT_HOSTS), args.days, Path(args.ca))
        if args.acl:
            cfg = acl.hub_config(listen=args.listen or ["tls/0.0.0.0:7447"], ca=str((out / "ca.pem").resolve()),
                                 cert=str((out / f"{args.hub}.pem").resolve()),
                                 key=str((out / f"{args.hub}.key").resolve()), gcs=args.gcs or ["gcs"], robots=robots,
                                 revoked=revoked_names(out))
            acl.write(cfg, Path(args.acl))
    except (CertError, ValueError) as exc:
        print(f"cromat certs: {exc}", file=sys.stderr)
        return 2
    print(f"cromat certs: hub {args.hub} in {out}" + (f"; hub router config {args.acl}" if args.acl else ""))
    return 0


def _from_manifest(path: str) -> tuple[Path, str, list[str], list[str]]:
    """(pki folder, robot, GCS identities, module identities incl. the RAL's) of a ``[bus.tls]`` manifest."""
    from module_manager.manifest import ManifestError, load_manifest  # only this form reads a manifest

    try:
        manifest = load_manifest(path, check_pki=False)
    except ManifestError as exc:
        raise CertError(f"manifest error: {exc}") from None
    tls = manifest.raw.bus.tls
    if tls is None or manifest.pki is None:
        raise CertError(f"{path}: no [bus.tls] section, so no certificates are needed")
    return manifest.pki, manifest.robot, list(tls.gcs), [manifest.identity(n) for n in manifest.modules]


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.hub:
        return _hub(args)
    if args.init_ca:
        if not args.ca:
            print("cromat certs: --init-ca needs --ca DIR (the operator's CA folder)", file=sys.stderr)
            return 2
        try:
            Path(args.ca).mkdir(parents=True, exist_ok=True)
            os.chmod(args.ca, 0o700)
            make_ca(Path(args.ca), args.ca_name)
        except (CertError, OSError) as exc:
            print(f"cromat certs: {exc}", file=sys.stderr)
            return 2
        print(f"cromat certs: CA in {args.ca} (keep it off the robot)")
        return 0
    listed = [m.strip() for m in (args.modules or "").split(",") if m.strip()]
    try:
        if args.manifest:
            pki, args.robot, gcs, modules = _from_manifest(args.manifest)
            gcs = args.gcs or gcs
            modules = [*modules, *(args.module or []), *listed]
            local = ["manager"]
            out = Path(args.dir) if args.dir else pki
        else:
            if not args.dir:
                raise CertError("give the output folder DIR (or --manifest)")
            out = Path(args.dir)
            gcs = args.gcs or ["gcs"]
            modules = [*(args.module or []), *listed] or ["module"]
            local = [] if args.no_local else [n for n in ("ral", "manager") if n not in modules]
    except CertError as exc:
        print(f"cromat certs: {exc}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    ca_dir = Path(args.ca) if args.ca else out.with_name(out.name + "-ca")
    ground = Path(args.ground) if args.ground else out.with_name(out.name + "-ground")
    if args.revoke:
        try:
            for name in args.revoke:
                revoke(ca_dir, _revoked_file(name, ground), [out, ground])
        except (CertError, ValueError) as exc:
            print(f"cromat certs: {exc}", file=sys.stderr)
            return 2
        print(f"cromat certs: revoked {', '.join(args.revoke)}; revocation list {out / CRL} and names "
              f"{out / REVOKED_NAMES} (copy both to every robot's folder; a running RAL reads the list again when it "
              f"changes; a launched robot's router, watching revoked.txt, denies the names within a second)")
        return 0
    try:
        if (out / f"{CA}.key").exists():
            raise CertError(f"{out / 'ca.key'}: a CA key in the robot's folder; move it to the operator's CA folder "
                            f"(--ca) and delete it here: whoever holds it can mint any identity")
        if ground.resolve() == out.resolve() or ca_dir.resolve() == out.resolve():
            raise CertError("the CA and ground-station folders must not be the robot folder")
        robot_side = [n for n in dict.fromkeys([*local, *modules]) if n not in gcs]
        again = [n for n in dict.fromkeys([*gcs, *robot_side]) if n in revoked_names(ca_dir)]
        if again:
            raise CertError(f"{', '.join(again)}: revoked (listed in {ca_dir / REVOKED_NAMES}); routers deny the name "
                            f"itself, so issue the station under a new name and list that one in [bus.tls] gcs")
        ca_dir.mkdir(parents=True, exist_ok=True)
        os.chmod(ca_dir, 0o700)
        make_ca(ca_dir, args.ca_name)
        make_leaf(out, "router", args.router_host or list(DEFAULT_HOSTS), args.days, ca_dir,
                  cn=None if args.robot == "*" else acl.mesh_router_cn(args.robot))
        for name in robot_side:
            make_leaf(out, name, None, args.days, ca_dir)
        for name in dict.fromkeys(gcs):
            make_leaf(ground, name, None, args.days, ca_dir)
        if args.acl:
            cfg = acl.router_config(
                listen=args.listen or ["tls/0.0.0.0:7447"],
                ca=str((out / "ca.pem").resolve()),
                cert=str((out / "router.pem").resolve()),
                key=str((out / "router.key").resolve()),
                robot=args.robot,
                gcs=gcs,
                modules=[m for m in dict.fromkeys(modules) if m not in ("ral", "manager")],
                revoked=revoked_names(out),
            )
            acl.write(cfg, Path(args.acl))
    except (CertError, ValueError) as exc:
        print(f"cromat certs: {exc}", file=sys.stderr)
        return 2
    print(
        f"cromat certs: robot folder {out} (router, {', '.join(robot_side)}; no CA key), ground folder {ground} "
        f"({', '.join(dict.fromkeys(gcs))}), CA in {ca_dir} (keep it off the robot)"
        + (f"; router config {args.acl}" if args.acl else "")
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
