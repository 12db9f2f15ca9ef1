"""The tools' pure parts: rates, validation of a datum to publish, rendering, key expressions, schemas."""

from __future__ import annotations

import msgspec
import numpy as np

from bbcs.contracts import gri
from bbcs.contracts.pan_tilt import DatosPT
from bbcs.wire import encoding_for
from cromat.tools import keyexpr
from cromat.tools.bus_cli import validate_datum
from cromat.tools.catalog import Catalog, Decoder, stand_in, type_from_encoding
from cromat.tools.mcapfmt import inline_refs
from cromat.tools.render import yamlish
from cromat.tools.stats import RateMeter


def test_rate_meter_rate_jitter_bytes_and_window():
    m = RateMeter(window_s=10.0)
    for i, t in enumerate([0.0, 0.1, 0.2, 0.35, 0.4]):
        m.add(t, 100 + i)
    r = m.rate(0.4)
    assert r.count == 5 and abs(r.hz - 10.0) < 1e-9
    assert abs(r.mean_interval_s - 0.1) < 1e-9 and abs(r.min_interval_s - 0.05) < 1e-9
    assert abs(r.max_interval_s - 0.15) < 1e-9 and abs(r.jitter_s - 0.0353553) < 1e-6
    assert abs(r.bytes_per_s - 510 / 0.4) < 1e-6
    assert m.rate(20.0).count == 0 and m.total == 5 and m.total_bytes == 510


def test_validate_datum_by_struct_and_by_schema_alone():
    value, reason = validate_datum('{"ref_pan": 10, "ref_tilt": -5}', DatosPT, {})
    assert value == DatosPT(ref_pan=10.0, ref_tilt=-5.0) and reason == ""
    assert validate_datum('{"ref_tilt": -95}', DatosPT, {})[1] == "field $.ref_tilt: Expected `float` >= -90.0"
    assert validate_datum("[1]", DatosPT, {})[1] == "the datum must be a JSON object of the slot's fields"
    assert validate_datum("{nope", DatosPT, {})[1].startswith("not JSON")
    schema = inline_refs(msgspec.json.schema(DatosPT))
    assert "$ref" not in str(schema) and schema["properties"]["ref_pan"]["maximum"] == 180.0
    assert validate_datum('{"ref_pan": 12.5}', None, schema) == ({"ref_pan": 12.5}, "")
    refused = validate_datum('{"ref_pan": 181}', None, schema)[1]
    assert refused == "field $.ref_pan: 181 is greater than the maximum of 180.0"


def test_decoder_types_and_falls_back_to_plain_msgpack():
    dec = Decoder("bbcs.contracts.pan_tilt:DatosPT")
    assert dec.decode(msgspec.msgpack.encode(DatosPT(ref_pan=3.0)))[0]["ref_pan"] == 3.0
    value, problem = dec.decode(msgspec.msgpack.encode({"ref_pan": 500.0}))
    assert value == {"ref_pan": 500.0} and problem.startswith("does not validate: Expected `float` <= 180.0")
    assert Decoder("no.such:Type").decode(msgspec.msgpack.encode([1, 2])) == ([1, 2], "")
    assert type_from_encoding("application/msgpack;bbcs.contracts.gri:GriState") == "bbcs.contracts.gri:GriState"
    assert type_from_encoding("zenoh/bytes") == ""
    cat = Catalog()
    assert cat.info("cromat/uav1/@ral/state").type == ""  # nobody described it, no sample yet
    info = cat.info("cromat/uav1/@ral/state", "application/msgpack;bbcs.contracts.gri:GriState")
    assert info.type == "bbcs.contracts.gri:GriState" and info.schema == msgspec.json.schema(gri.GriState)
    unknown = cat.info("cromat/uav1/x/y", "application/msgpack;elsewhere.structs:Thing")
    assert unknown.type == "elsewhere.structs:Thing" and unknown.schema == {}  # not installed here
    assert str(encoding_for(stand_in("elsewhere.structs:Thing"))) == "application/msgpack;elsewhere.structs:Thing"


def test_keyexpr_helpers():
    assert keyexpr.expand("uav1/dsp/telemetry") == "cromat/uav1/dsp/telemetry"
    assert keyexpr.expand("cromat/uav1/**") == "cromat/uav1/**"
    assert keyexpr.remap_robot("cromat/uav1/@ral/state", "uav1", "uav9") == "cromat/uav9/@ral/state"
    assert keyexpr.remap_robot("cromat/uav2/x/y", "uav1", "uav9") == "cromat/uav2/x/y"
    assert keyexpr.intersects("cromat/uav1/*/*", "cromat/uav1/dsp/telemetry")
    assert not keyexpr.intersects("cromat/uav1/*/*", "cromat/uav1/@ral/state")
    assert "cromat/uav1/@ral/*" in keyexpr.everything("uav1")


def test_yamlish_shows_nesting_and_lists():
    lines = yamlish({"a": 1.5, "b": {"c": None, "d": "x y"}, "e": [{"f": True}, {"f": False}], "g": []})
    assert lines == ["a: 1.5", "b:", "  c: null", "  d: x y", "e:", "  - f: true", "  - f: false", "g: []"]


def test_yamlish_cuts_packed_arrays_but_json_keeps_them():
    import base64

    from bbcs.contracts.lidar import LidarScan, pack_points
    points, xyz, layer = pack_points(np.zeros((100, 3)), np.zeros(100))
    value = msgspec.to_builtins(LidarScan(stamp=1.0, scan_number=7, index=1, points=points, xyz=xyz, layer=layer))
    lines = yamlish(value)
    assert "xyz: \"AAAA" in "\n".join(lines) and "(1600 chars; --json prints it whole)" in "\n".join(lines)
    assert all(len(line) < 220 for line in lines)  # the 100-byte layer (136 chars) is short enough to keep
    assert base64.b64decode(msgspec.json.decode(msgspec.json.encode(value))["xyz"]) == xyz


class Tree(msgspec.Struct):
    name: str
    children: list[Tree] = []


def test_inline_refs_gives_the_root_once_and_no_refs():
    """Issue 34 item 7: the recordings' and the bridge's schemas are inlined: no ``$ref``, no ``$defs``, the
    root struct not repeated (GriState's was 25.8 KB with a second copy of everything under ``$defs``)."""
    raw = msgspec.json.schema(gri.GriState)
    text = msgspec.json.encode(inline_refs(raw)).decode()
    assert '"$ref"' not in text and '"$defs"' not in text
    assert len(text) < 1.1 * len(msgspec.json.encode(raw))
    assert inline_refs(raw)["properties"]["telemetry"]["anyOf"][0]["title"] == "RobotTelemetry"
    tree = inline_refs(msgspec.json.schema(Tree))  # a struct inside itself: the one reference that must stay
    assert tree["title"] == "Tree" and tree["properties"]["children"]["items"] == {"$ref": "#/$defs/Tree"}
    assert tree["$defs"]["Tree"]["properties"]["children"]["items"] == {"$ref": "#/$defs/Tree"}


def test_the_recorder_writes_in_log_time_order_and_events_at_their_own_stamps(tmp_path):
    """Issue 34 item 7: samples handed over out of order (the subscriptions' threads) are written in log-time
    order; a GRI event from the RAL's cache at its own stamp, before the rest; one later than the window is said."""
    from mcap.reader import make_reader

    from cromat.tools.catalog import Catalog
    from cromat.tools.record import McapSink

    sink = McapSink(tmp_path / "o.mcap", Catalog(), split=False)
    enc = str(encoding_for(DatosPT))
    t0 = 1_795_000_000_000_000_000
    for ms in (30, 10, 20, 50, 40):
        sink.write("cromat/r/ral/pt_datos", msgspec.msgpack.encode(DatosPT(ref_pan=ms)), t0 + ms * 1_000_000, enc)
    cached = gri.GriEvent(robot="r", stamp=(t0 - 5_000_000_000) / 1e9, kind="task_accepted")
    sink.write("cromat/r/@ral/events", msgspec.msgpack.encode(cached), t0 + 60_000_000,
               str(encoding_for(gri.GriEvent)))
    sink.flush(everything=True)
    sink.write("cromat/r/ral/pt_datos", msgspec.msgpack.encode(DatosPT(ref_pan=0)), t0, enc)  # came too late
    sink.close()
    with open(tmp_path / "o.mcap", "rb") as f:
        got = [(m.log_time - t0) // 1_000_000 for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert got == [-5000, 10, 20, 30, 40, 50, 0]
    assert sink.summary.late == 1 and "1 written out of log-time order" in sink.summary.lines()[1]
