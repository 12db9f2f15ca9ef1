"""A robot's fleet trust and two ground stations' signing keys, issued by ``cromat certs`` into a test's folder:
what the signed-task and replay tests sign with and check against."""

from __future__ import annotations

from pathlib import Path

from bbcs.signing import FleetTrust, StationSigner
from cromat import certs


class Pki:
    """A robot folder (its CA, its revocation list) and the ground folder of stations ``gcs1`` and ``gcs2``."""

    def __init__(self, root: Path) -> None:
        self.robot, self.ground = root / "robot", root / "robot-ground"
        assert certs.main([str(self.robot), "--gcs", "gcs1", "--gcs", "gcs2"]) == 0
        self.root = root

    def signer(self, name: str) -> StationSigner:
        return StationSigner.from_files(self.ground / f"{name}.pem", self.ground / f"{name}.key")

    def trust(self) -> FleetTrust:
        return FleetTrust.from_files(self.robot / "ca.pem", ["gcs1", "gcs2"], self.robot / "crl.pem")
