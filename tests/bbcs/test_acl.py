"""The access-policy generator and the shipped Zenoh templates."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from bbcs import acl

ROOT = Path(__file__).resolve().parents[2]
TEMPLATES = ROOT / "bbcs_conf" / "zenoh"


def _load(path: Path) -> dict:
    text = path.read_text()
    return json.loads("\n".join(line for line in text.splitlines() if not line.startswith("//")))


def test_shipped_router_template_is_the_generator_output() -> None:
    expected = acl.router_config(
        listen=["tls/0.0.0.0:7447"],
        ca="/etc/cromat/pki/ca.pem",
        cert="/etc/cromat/pki/router.pem",
        key="/etc/cromat/pki/router.key",
        robot="uav1",
        gcs=["gcs"],
        modules=["dsp", "telemetry", "pan_tilt", "path_follower", "vision"],
    )
    assert _load(TEMPLATES / "robot_router_secure.json5") == expected


@pytest.mark.parametrize("name", ["robot_router_secure.json5", "gcs_client.json5"])
def test_templates_are_valid_zenoh_configs(name: str) -> None:
    zenoh.Config.from_file(str(TEMPLATES / name))


def test_only_gcs_may_submit_tasks_and_modules_write_their_own_slots() -> None:
    cfg = acl.router_config(
        listen=["tls/127.0.0.1:1"],
        ca="c",
        cert="r",
        key="k",
        robot="r1",
        gcs=["g1", "g2"],
        modules=["vision"],
    )["access_control"]
    rules = {r["id"]: r for r in cfg["rules"]}
    policies = {p["id"]: p for p in cfg["policies"]}
    granting_task = {
        p["id"]
        for p in cfg["policies"]
        for rid in p["rules"]
        if "query" in rules[rid]["messages"] and "cromat/r1/@ral/task" in rules[rid]["key_exprs"]
    }
    assert granting_task == {"gcs"}
    assert policies["m-vision"]["rules"] == ["m-vision-write", "m-vision-token", "m-vision-no-control",
                                            "m-vision-no-control-pub"]
    assert all(k.startswith("cromat/r1/vision/") for k in rules["m-vision-write"]["key_exprs"])
    assert rules["m-vision-no-control"]["permission"] == "deny"
    assert "cromat/r1/vision/control_entrada" in rules["m-vision-no-control"]["key_exprs"]
    assert cfg["default_permission"] == "deny"


def test_bad_identities_are_refused() -> None:
    with pytest.raises(ValueError):
        acl.router_config(listen=[], ca="c", cert="r", key="k", gcs=[], modules=[])
    with pytest.raises(Exception, match="identity"):
        acl.router_config(listen=[], ca="c", cert="r", key="k", gcs=["g/x"], modules=[])
