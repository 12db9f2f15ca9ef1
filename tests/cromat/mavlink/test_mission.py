"""The mission transfer protocol (cromat/mavlink/mission.py) as a state machine, its clock injected."""

from __future__ import annotations

from cromat.mavlink.dialect import mav
from cromat.mavlink.mission import Ack, Cleared, MissionTransfer, RequestItem, SendCount, SendItem, Uploaded
from cromat.mavlink.plan import Item

GCS = (255, 190)
OTHER = (254, 1)


def item(seq: int, mission_type: int = 0) -> Item:
    return Item(seq=seq, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command=mav.MAV_CMD_NAV_WAYPOINT,
                x=374117000 + seq, y=-60025000, z=15.0, mission_type=mission_type)


def test_upload_asks_each_item_in_order_and_hands_over_the_whole_mission() -> None:
    t = MissionTransfer()
    assert t.on_count(GCS, 3, 0, now=0.0) == [RequestItem(GCS, 0, 0)]
    assert t.on_item(GCS, item(0), now=0.1) == [RequestItem(GCS, 1, 0)]
    assert t.on_item(GCS, item(1), now=0.2) == [RequestItem(GCS, 2, 0)]
    out = t.on_item(GCS, item(2), now=0.3)
    assert out == [Uploaded(GCS, [item(0), item(1), item(2)], 0)]
    assert t.upload is None


def test_a_lost_item_is_asked_again_then_the_upload_is_cancelled() -> None:
    t = MissionTransfer(retry_s=1.0, retries=2)
    t.on_count(GCS, 2, 0, now=0.0)
    t.on_item(GCS, item(0), now=0.1)  # item 1 is lost
    assert t.tick(1.0) == []
    assert t.tick(1.2) == [RequestItem(GCS, 1, 0)]
    assert t.tick(2.3) == [RequestItem(GCS, 1, 0)]
    out = t.tick(3.4)
    assert len(out) == 1 and isinstance(out[0], Ack) and out[0].result == mav.MAV_MISSION_OPERATION_CANCELLED
    assert "item 1" in out[0].reason and t.upload is None
    # the retry after a loss gets the item: the upload completes
    t = MissionTransfer(retry_s=1.0)
    t.on_count(GCS, 2, 0, now=0.0)
    t.on_item(GCS, item(0), now=0.1)
    assert t.tick(1.2) == [RequestItem(GCS, 1, 0)]
    assert t.on_item(GCS, item(1), now=1.3) == [Uploaded(GCS, [item(0), item(1)], 0)]


def test_items_out_of_order_and_duplicates() -> None:
    t = MissionTransfer()
    t.on_count(GCS, 3, 0, now=0.0)
    t.on_item(GCS, item(0), now=0.1)
    assert t.on_item(GCS, item(2), now=0.2) == [RequestItem(GCS, 1, 0)]  # item 1 skipped: asked for again
    assert t.on_item(GCS, item(0), now=0.3) == []  # a duplicate of one already kept
    assert t.on_item(GCS, item(1), now=0.4) == [RequestItem(GCS, 2, 0)]
    assert t.on_item(OTHER, item(2), now=0.5) == []  # not this upload's ground station


def test_empty_upload_clears_and_a_second_station_is_denied_meanwhile() -> None:
    t = MissionTransfer()
    assert t.on_count(GCS, 0, 0, now=0.0) == [Uploaded(GCS, [], 0)]
    t.on_count(GCS, 2, 0, now=0.0)
    out = t.on_count(OTHER, 1, 0, now=0.1)
    assert isinstance(out[0], Ack) and out[0].result == mav.MAV_MISSION_DENIED
    assert isinstance(t.on_clear(OTHER, 0)[0], Ack)
    t.on_ack(GCS, 0)  # the station gave up its upload
    assert t.on_clear(OTHER, 0) == [Cleared(OTHER, 0)]


def test_download_counts_then_sends_each_item_asked() -> None:
    stored = {0: [item(0), item(1)], 1: [item(0, 1)]}
    t = MissionTransfer(stored, idle_s=5.0)
    assert t.on_request_list(GCS, 0, now=0.0) == [SendCount(GCS, 2, 0)]
    assert t.on_request(GCS, 1, 0, now=0.1) == [SendItem(GCS, item(1))]
    assert t.on_request(GCS, 0, 0, now=0.2) == [SendItem(GCS, item(0))]
    bad = t.on_request(GCS, 5, 0, now=0.3)
    assert isinstance(bad[0], Ack) and bad[0].result == mav.MAV_MISSION_INVALID_SEQUENCE
    t.on_ack(GCS, 0)
    assert t.download is None
    # the fence is another mission type; an empty one answers count 0 and holds no transfer
    assert t.on_request_list(GCS, 1, now=1.0) == [SendCount(GCS, 1, 1)]
    assert t.on_request_list(GCS, 2, now=1.0) == [SendCount(GCS, 0, 2)] and t.download is None
    # items given for this download (the robot's running path) are sent instead of the stored ones
    assert t.on_request_list(GCS, 0, now=2.0, items=[item(7)]) == [SendCount(GCS, 1, 0)]
    assert t.on_request(GCS, 0, 0, now=2.1) == [SendItem(GCS, item(7))]
    assert t.tick(7.2) == [] and t.download is None  # a quiet station's download is dropped


def test_item_request_outside_a_download_is_an_error() -> None:
    out = MissionTransfer().on_request(GCS, 0, 0, now=0.0)
    assert isinstance(out[0], Ack) and out[0].result == mav.MAV_MISSION_ERROR
