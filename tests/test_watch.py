"""afford watch never waits for what will not come: a busy assembler skips scans, and the map that covers the
last scan published says so (Cloud.scans_received, carried to the fields and maps), so the watch finishes on
it however many scans were fused."""

from __future__ import annotations

import time

import numpy as np

from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import get_skeleton
from affordcore.mapping.maps import build_map
from affordwire import messages
from services.clients import MapWatcher
from services.node import Inbound, Inbox
from services.transport import Keys, encoding_of


def _item(age: float = 0.0) -> Inbound:
    return Inbound("scan/camera", "s", "e", b"x" * 10, time.time() - age)


def test_an_inbox_counts_the_inputs_it_is_done_with_taken_skipped_or_refused():
    inbox = Inbox(latest_only=False, limit=8, max_bytes=10**6, max_lag=0.5, max_gap=0.25)
    late = [_item(age=5.0 - 0.1 * k) for k in range(9)] + [_item()]  # a 10 Hz stream, all but the last late
    for item in late:
        inbox.offer(item)
    assert inbox.settled() == 2  # eight wait; the ninth and tenth were refused (MAX_QUEUE)
    taken = 0
    while inbox.take(0.05) is not None:
        taken += 1
        # every input offered is accounted for: waiting, or settled (taken, passed over, refused)
        assert inbox.settled() + len(inbox) == 10
    assert taken + inbox.skipped + 2 == inbox.settled() == 10
    assert inbox.skipped > 0  # the stream was thinned, and still every scan counts as covered


class _Sample:
    """What a zenoh sample shows a subscriber: its key, encoding and payload."""

    def __init__(self, key: str, message):
        self.key_expr, self.encoding = key, encoding_of(type(message))
        self.payload = _Payload(message.SerializeToString())


class _Payload:
    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def _map(affordance: str, frames: int, scans_received: int, at: float) -> messages.AffordanceMapMessage:
    """A small real map message of a cloud stamped `at`, of `frames` fused scans out of `scans_received`."""
    grid = PoseGrid(np.arange(4) * 0.1, np.arange(3) * 0.1, np.array([0.5]), np.arange(4) * np.pi / 2)
    amap = build_map(affordance, np.zeros(grid.shape), grid, get_skeleton(affordance), threshold=1.0)
    cloud = messages.cloud_message(np.zeros((100, 3)), np.eye(4), "assembler", frames, at, scans_received)
    fields = messages.SceneFieldsMessage()
    messages._carry_source(fields, cloud.world_from_input, cloud, at)
    return messages.map_message(amap, "m", fields, at)


def test_the_watch_takes_the_map_that_covers_every_scan_published_however_many_were_fused():
    keys, lines = Keys("r1"), []
    watcher = MapWatcher(keys, ["sitting-working"], min_frames=100, out=None, echo=lines.append)
    key = keys.affordance("sitting-working")
    watcher.on_sample(_Sample(key, _map("sitting-working", frames=40, scans_received=60, at=10.0)))
    assert not watcher.done.is_set()
    assert "covering 100 scans (the newest map seen covers 60)" in watcher.waiting_for()
    # the assembler skipped 80 of 100 scans to keep up: 20 fused, all 100 covered
    watcher.on_sample(_Sample(key, _map("sitting-working", frames=20, scans_received=100, at=11.0)))
    assert watcher.done.is_set() and watcher.received["sitting-working"]["affordance"] == "sitting-working"


def test_a_map_of_a_service_that_does_not_count_received_scans_is_judged_by_the_scans_it_fused():
    keys = Keys("r1")
    watcher = MapWatcher(keys, ["standing-working"], min_frames=30, out=None, echo=lambda line: None)
    key = keys.affordance("standing-working")
    watcher.on_sample(_Sample(key, _map("standing-working", frames=29, scans_received=0, at=10.0)))
    assert not watcher.done.is_set()
    watcher.on_sample(_Sample(key, _map("standing-working", frames=30, scans_received=0, at=11.0)))
    assert watcher.done.is_set()


def _assembler_status(no_output: str, accepted: int, skipped: int) -> messages.Status:
    return messages.Status(service="assembler", no_output=no_output, accepted=accepted, skipped=skipped)


def test_the_watch_stops_at_once_when_the_assembler_has_every_scan_and_no_map_of_them():
    keys = Keys("r1")
    watcher = MapWatcher(keys, ["sitting-working"], min_frames=100, out=None, echo=lambda line: None)
    status_key = keys.status("assembler")
    no_map = "9 frames, no map yet: no floor in view"
    # mid-stream, a failed try says nothing about the map of every scan
    watcher.on_sample(_Sample(status_key, _assembler_status(no_map, accepted=5, skipped=40)))
    watcher.on_sample(_Sample(status_key, _assembler_status("", accepted=9, skipped=91)))
    assert not watcher.done.is_set() and watcher.gave_up is None
    watcher.on_sample(_Sample(status_key, _assembler_status(no_map, accepted=9, skipped=91)))
    assert watcher.done.is_set() and "all 100 scans" in watcher.gave_up and "no floor" in watcher.gave_up
    # a watch not counting scans never gives up, nor does one on another service's status
    uncounted = MapWatcher(keys, ["sitting-working"], min_frames=0, out=None, echo=lambda line: None)
    uncounted.on_sample(_Sample(status_key, _assembler_status(no_map, accepted=9, skipped=91)))
    other = MapWatcher(keys, ["sitting-working"], min_frames=100, out=None, echo=lambda line: None)
    other.on_sample(_Sample(keys.status("features"), _assembler_status(no_map, accepted=100, skipped=0)))
    assert not uncounted.done.is_set() and not other.done.is_set()


def _refusal(key_robot: Keys, source: str, at: float | None, scans: int = 0) -> _Sample:
    """A features service's refusal of a cloud from `source` stamped `at` (None: one that names no cloud)."""
    error = messages.Error(service="features", key=key_robot.cloud, reason="no floor", input_source=source)
    error.input_scans = scans
    if at is not None:
        error.input_timestamp.FromNanoseconds(int(at * 1e9))
    return _Sample(key_robot.error("features"), error)


def test_a_stream_watch_ends_only_on_the_refusal_of_the_assembler_s_cloud_covering_its_scans():
    """Another client's refused cloud (the far-off points of a burst of hostile clouds) is shown, not taken as
    the answer; the assembler's own cloud of the scans waited for, refused, is the answer."""
    keys, lines = Keys("r1"), []
    watcher = MapWatcher(
        keys, ["sitting-working"], min_frames=20, out=None, echo=lines.append, since=int(5e9)
    )
    for sample in (
        _refusal(keys, "fuzz", 9.0),  # someone else's cloud
        _refusal(keys, "assembler", 9.0, scans=12),  # the assembler's, of fewer scans than waited for
        _refusal(keys, "assembler", 4.0, scans=30),  # of an older stream than the newest cloud at the start
        _refusal(keys, "assembler", None, scans=30),  # naming no cloud
    ):
        watcher.on_sample(sample)
    assert not watcher.done.is_set() and watcher.refused is None
    assert sum("not the cloud waited for" in line for line in lines) == 4
    assert any(
        "REJECTED 'fuzz' stamped 9.000000000 on afford/@v1/r1/map/cloud: no floor" in line for line in lines
    )
    # a refusal kept from before the watch began is an earlier stream's: shown, not taken
    watcher.on_sample(_refusal(keys, "assembler", 9.0, scans=20), live=False)
    assert not watcher.done.is_set()
    watcher.on_sample(_refusal(keys, "assembler", 9.5, scans=20))
    assert watcher.done.is_set() and watcher.refused == "no floor"
    assert watcher.refused_cloud == "'assembler' stamped 9.500000000 (20 scans)"


def test_a_watch_of_one_cloud_ends_on_its_refusal_kept_or_live_and_on_no_other():
    keys = Keys("r1")
    watcher = MapWatcher(keys, ["sitting-working"], 0, None, echo=lambda line: None, since=int(7.25e9))
    watcher.on_sample(_refusal(keys, "example", 7.5))
    watcher.on_sample(_refusal(keys, "example", 7.0), live=False)
    assert not watcher.done.is_set()
    watcher.on_sample(
        _refusal(keys, "example", 7.25), live=False
    )  # kept by the service, fetched at the start
    assert watcher.done.is_set() and watcher.refused_cloud.startswith("'example' stamped 7.250000000")
    # a watch of the newest cloud when the service has none waits for a cloud; no refusal is its answer
    none_yet = MapWatcher(keys, ["sitting-working"], 0, None, echo=lambda line: None)
    none_yet.on_sample(_refusal(keys, "example", 7.25))
    assert not none_yet.done.is_set()


def test_a_latest_only_inbox_gives_back_the_input_a_refused_one_superseded():
    inbox = Inbox(latest_only=True, limit=8, max_bytes=10**6)
    good, bad, later = _item(), _item(), _item()
    inbox.offer(good)
    inbox.offer(bad)  # supersedes the good one, which is set aside
    assert inbox.skipped == 1 and inbox.take(0.05) is bad
    assert inbox.give_back(bad) is good  # bad was refused: good is worked on after all
    assert inbox.skipped == 0 and inbox.take(0.05) is good and inbox.take(0.01) is None
    # once an input is answered, what was set aside before it is not wanted
    inbox.offer(bad)
    inbox.offer(later)
    assert inbox.take(0.05) is later
    inbox.settle(later)
    assert inbox.give_back(later) is None
    # nor is anything given back while a newer input waits: that one supersedes it anyway
    inbox.offer(good)
    inbox.offer(bad)
    assert inbox.take(0.05) is bad
    inbox.offer(later)
    assert inbox.give_back(bad) is None and inbox.take(0.05) is later
