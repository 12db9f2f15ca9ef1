"""A robot's fleet trust and two ground stations' signing keys, issued by ``cromat certs`` into a test's folder:
what the signed-task and replay tests sign with and check against."""

from __future__ import annotations

import shutil
from pathlib import Path

from bbcs.signing import FleetTrust, StationSigner
from cromat import certs


class Pki:
    """A robot folder (its CA, its revocation list) and the ground folder of stations ``gcs1`` and ``gcs2``."""

    def __init__(self, root: Path) -> None:
        self.robot, self.ground = root / "robot", root / "robot-ground"
        assert certs.main([str(self.robot), "--gcs", "gcs1", "--gcs", "gcs2"]) == 0
        self.root = root

    @classmethod
    def copy_of(cls, template: Pki, root: Path) -> Pki:
        """``template``'s folders copied into ``root``: issuing them takes ``openssl`` runs of a second or more,
        and a test that revokes a station changes only its own copy."""
        shutil.copytree(template.root, root, dirs_exist_ok=True)
        pki = cls.__new__(cls)
        pki.robot, pki.ground, pki.root = root / "robot", root / "robot-ground", root
        return pki

    def signer(self, name: str) -> StationSigner:
        return StationSigner.from_files(self.ground / f"{name}.pem", self.ground / f"{name}.key")

    def trust(self) -> FleetTrust:
        return FleetTrust.from_files(self.robot / "ca.pem", ["gcs1", "gcs2"], self.robot / "crl.pem")
