"""ROS 2 out: affordance maps as PoseArray, MarkerArray and OccupancyGrid (affordwire.ros_maps), decoded with
rosbags; and the inference service publishing them on rmw_zenoh's keys, latched, read as rmw_zenoh's
TRANSIENT_LOCAL subscription reads them (a zenoh AdvancedSubscriber with history, on the real type hash)."""

from __future__ import annotations

import contextlib
import math
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rosbags")

from affordwire import messages, ros, ros_maps  # noqa: E402

STORE = ros.typestore()
LOWEST = float(np.finfo(np.float32).min)  # the map's "no pose tried"


def small_map(skeletons=((1.1, 2.2, 0.45, 0.5, 0.9, 0.83), (1.25, 2.05, 0.4, -2.0, 0.7, 0.61))):
    """A 4 x 3 map at 0.1 m (cell centres from x0 = 1.05, y0 = 2.05), threshold 0.2, one cell not tried."""
    message = messages.AffordanceMapMessage(frame_id="world", affordance="sitting-relaxing", threshold=0.2)
    spec = message.grid
    spec.x0, spec.y0, spec.step, spec.nx, spec.ny = 1.05, 2.05, 0.1, 4, 3
    confidence = np.array([[0.1, 0.2, 0.3], [0.5, 0.9, 0.55], [LOWEST, 0.25, 0.7], [0.21, 0.0, 0.6]])
    message.confidence = confidence.astype("<f4").tobytes()
    for x, y, z, theta, score, probability in skeletons:
        message.skeletons.add(x=x, y=y, z=z, theta=theta, score=score, probability=probability)
    message.cloud_timestamp.FromNanoseconds(1_700_000_000_250_000_000)
    return message, confidence


def decode(payload: bytes, typename: str):
    return STORE.deserialize_cdr(payload, typename)


def yaw_of(q) -> float:
    assert abs(q.x) < 1e-12 and abs(q.y) < 1e-12 and abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9
    return math.atan2(2 * q.w * q.z, 1 - 2 * q.z**2)


def check_places(places, message, frame="world") -> None:
    assert places.header.frame_id == frame
    assert (places.header.stamp.sec, places.header.stamp.nanosec) == (1_700_000_000, 250_000_000)
    assert len(places.poses) == len(message.skeletons)
    for pose, skeleton in zip(places.poses, message.skeletons):
        p = pose.position
        assert (p.x, p.y, p.z) == pytest.approx((skeleton.x, skeleton.y, skeleton.z))
        assert yaw_of(pose.orientation) == pytest.approx(skeleton.theta)


def check_confidence(grid, message, confidence) -> None:
    spec = message.grid
    info = grid.info
    assert (info.width, info.height) == (spec.nx, spec.ny)
    assert info.resolution == pytest.approx(spec.step)
    origin = info.origin.position
    assert (origin.x, origin.y) == pytest.approx((spec.x0 - spec.step / 2, spec.y0 - spec.step / 2))
    cells = np.asarray(grid.data, dtype=np.int64).reshape(info.height, info.width)  # rows along y
    for i in range(spec.nx):
        for j in range(spec.ny):
            # the cell holding world (x0 + i step, y0 + j step), as a ROS user indexes it
            col = int((spec.x0 + i * spec.step - origin.x) / info.resolution)
            row = int((spec.y0 + j * spec.step - origin.y) / info.resolution)
            value = cells[row, col]
            if confidence[i, j] == LOWEST:
                assert value == -1
            elif confidence[i, j] <= message.threshold:
                assert value == 0
            else:
                assert 0 <= value <= 100
    tried = confidence > LOWEST
    order = np.argsort(confidence[tried], kind="stable")
    values = cells.T[tried][order]
    assert (np.diff(values) >= 0).all(), "cells follow the confidence"
    assert values[-1] == 100 and cells.T[np.unravel_index(np.argmax(confidence), confidence.shape)] == 100


def check_markers(markers, message, colour) -> None:
    kinds = [m.type for m in markers.markers]
    assert markers.markers[0].action == 3  # DELETEALL: a map with fewer places clears the old ones
    texts = [m.text for m in markers.markers if m.type == 9]
    assert texts == [f"p {s.probability:.2f}" for s in message.skeletons]
    arrows = [m for m in markers.markers if m.type == 0 and m.action == 0]
    assert len(arrows) == len(message.skeletons) and kinds.count(9) == len(message.skeletons)
    for arrow, skeleton in zip(arrows, message.skeletons):
        assert (arrow.pose.position.x, arrow.pose.position.y) == pytest.approx((skeleton.x, skeleton.y))
        assert yaw_of(arrow.pose.orientation) == pytest.approx(skeleton.theta)
        assert (arrow.color.r, arrow.color.g, arrow.color.b) == pytest.approx(colour[:3])
        assert arrow.ns == message.affordance


# -- the encoders --------------------------------------------------------------------------------------------


def test_places_are_poses_with_the_yaw_in_the_maps_order():
    message, _ = small_map()
    check_places(decode(ros_maps.pose_array(message, "world"), ros_maps.PLACES), message)
    assert decode(ros_maps.pose_array(message, "map"), ros_maps.PLACES).header.frame_id == "map"


def test_the_confidence_grid_has_the_maps_cells_scaled_from_threshold_to_best():
    message, confidence = small_map()
    check_confidence(
        decode(ros_maps.occupancy_grid(message, "world"), ros_maps.CONFIDENCE), message, confidence
    )


def test_a_map_with_nothing_above_its_threshold_is_all_zero_where_tried():
    message, confidence = small_map(skeletons=())
    message.threshold = 5.0
    cells = ros_maps.confidence_cells(message)
    assert sorted(set(cells.tolist())) == [-1, 0] and (cells == -1).sum() == 1


def test_markers_carry_each_places_probability_in_the_affordances_colour():
    message, _ = small_map()
    colour = (0.1, 0.6, 0.3, 1.0)
    check_markers(decode(ros_maps.marker_array(message, "world", colour), ros_maps.MARKERS), message, colour)


def test_markers_of_a_map_without_places_say_so():
    message, _ = small_map(skeletons=())
    markers = decode(ros_maps.marker_array(message, "world", (1, 0, 0)), ros_maps.MARKERS).markers
    assert [m.action for m in markers] == [3, 0]
    assert markers[1].text == "sitting-relaxing: no place found"


def test_type_hashes_are_jazzys():
    """The hashes rmw_zenoh puts in its keys, as `ros2 topic info -v` prints them on Jazzy."""
    assert ros_maps.type_hash(ros_maps.PLACES) == (
        "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0"
    )
    assert ros_maps.type_hash(ros_maps.CONFIDENCE) == (
        "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7"
    )
    assert ros_maps.type_hash(ros_maps.MARKERS) == (
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"
    )


def test_humble_keys_carry_no_type_hash_and_tokens_write_qos_as_rmw_zenoh(monkeypatch):
    """Humble has no type hashes: its rmw_zenoh keys say TypeHashNotSupported, and a key with a hash would
    match no Humble subscriber. The tokens' QoS leaves out what equals rmw_zenoh's default QoS."""
    from services.ros_maps import TOKEN_QOS, rmw_zenoh_key
    from services.settings import ServiceSettings

    topic = "/robot1/affordances/sitting_relaxing/places"
    assert rmw_zenoh_key(0, topic, ros_maps.PLACES, "humble") == (
        "0/robot1/affordances/sitting_relaxing/places/geometry_msgs::msg::dds_::PoseArray_/TypeHashNotSupported"
    )
    assert rmw_zenoh_key(0, topic, ros_maps.PLACES).endswith(ros_maps.type_hash(ros_maps.PLACES))
    monkeypatch.setenv("AFFORD_ROS__DISTRIBUTION", "humble")
    assert ServiceSettings().ros.distribution == "humble"
    # reliable, keep-last: rmw_zenoh's defaults, left out; transient local (1) and depth 1 written
    assert TOKEN_QOS == ":1:,1:,:,:,,"


def test_topic_names_are_ros_names_and_settings_are_checked(monkeypatch):
    from pydantic import ValidationError

    from services.ros_maps import attachment, map_topics, rmw_zenoh_key
    from services.settings import ServiceSettings

    assert map_topics("/{robot}/affordances", "lab-1", "sitting-relaxing") == {
        "places": "/lab_1/affordances/sitting_relaxing/places",
        "markers": "/lab_1/affordances/sitting_relaxing/markers",
        "confidence": "/lab_1/affordances/sitting_relaxing/confidence",
    }
    assert rmw_zenoh_key(3, "/a/b/places", ros_maps.PLACES) == (
        f"3/a/b/places/geometry_msgs::msg::dds_::PoseArray_/{ros_maps.type_hash(ros_maps.PLACES)}"
    )
    # rmw_zenoh's attachment, as zenoh-ext serialises (int64, int64, 16 bytes as a sequence)
    import zenoh.ext

    gid = bytes(range(16))
    expected = zenoh.ext.z_serialize((zenoh.ext.Int64(7), zenoh.ext.Int64(123), gid)).to_bytes()
    assert attachment(7, 123, gid) == expected
    for name, value, reason in [
        ("AFFORD_ROS__MAPS_NAMESPACE", "/a b", "not a ROS 2 namespace"),
        ("AFFORD_ROS__MAPS_NAMESPACE", "/{robot}/*", "not a ROS 2 namespace"),
        ("AFFORD_ROS__MAPS_FRAME_ID", "my frame", "not a tf frame"),
    ]:
        monkeypatch.setenv(name, value)
        with pytest.raises(ValidationError, match=reason):
            ServiceSettings()
        monkeypatch.delenv(name)


# -- the inference service: rmw_zenoh keys, latched ----------------------------------------------------------


@pytest.fixture(scope="module")
def fields():
    from affordcore.example import example_room
    from affordcore.geometry.fields import compute_fields

    cloud = messages.cloud_message(example_room(points_per_m2=300.0).points, np.eye(4), "test", at=1.7e9)
    return messages.fields_message(compute_fields(messages.cloud_points(cloud)), cloud, at=1.7e9)


@contextlib.contextmanager
def running_inference(settings, models, rrd):
    """An inference service of robot-1 on a router of its own, in a thread: its client session while in the
    block; on leaving, the service stopped (its thread ended) and the sessions closed."""
    from services.inference import InferenceService
    from services.launch import free_port
    from services.node import Node
    from services.transport import open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session([], mode="router", listen=[endpoint])
    node = Node("inference", "robot-1", [endpoint], settings, rrd=rrd, models=models)
    thread = threading.Thread(target=InferenceService(node).run, daemon=True)
    thread.start()
    client = open_session([endpoint])
    try:
        yield client
    finally:
        node.stop_event.set()
        thread.join(30)
        client.close()
        router.close()
    assert not thread.is_alive()


def test_the_inference_service_publishes_latched_maps_on_rmw_zenoh_keys(fields, tmp_path, monkeypatch):
    import zenoh
    import zenoh.ext
    from conftest import eventually

    from affordcore.geometry.features import FeatureLayout
    from affordcore.labels import affordance_colours
    from affordcore.learn.model import choose_models
    from services.ros_maps import TOPICS, map_topics, rmw_zenoh_key
    from services.settings import ServiceSettings
    from services.transport import Keys, put_message

    monkeypatch.setenv("AFFORD_ROS__MAPS", "true")
    monkeypatch.setenv("AFFORD_ROS__DOMAIN_ID", "7")
    settings = ServiceSettings()
    models = choose_models([], [], FeatureLayout.from_settings(settings))[:1]
    affordance = models[0].affordance
    topics = map_topics(settings.ros.maps_namespace, "robot-1", affordance)
    keys = {kind: rmw_zenoh_key(7, topic, TOPICS[kind]) for kind, topic in topics.items()}

    live, late, maps = {}, {}, []
    with running_inference(settings, models, tmp_path / "i.rrd") as client:
        afford_keys = Keys("robot-1")
        held = [
            client.declare_subscriber(afford_keys.affordance(affordance), lambda s: maps.append(s)),
            # a volatile ROS subscription: samples as they come, with rmw_zenoh's attachment
            *[
                client.declare_subscriber(key, lambda s, kind=kind: live.setdefault(kind, []).append(s))
                for kind, key in keys.items()
            ],
        ]
        # the ROS graph: a publisher token per topic, with its type and hash (ros2 topic list reads these)
        tokens = [str(r.ok.key_expr) for r in client.liveliness().get("@ros2_lv/7/**", timeout=5) if r.ok]
        for kind, topic in topics.items():
            typename = TOPICS[kind]
            assert any(
                f"/MP/%/%/afford_inference_robot_1/{topic.replace('/', '%')}/" in t
                and ros_maps.type_hash(typename) in t
                for t in tokens
            ), tokens
        for k in range(2):  # two maps: a late subscriber must get the second only
            message = messages.SceneFieldsMessage()
            message.CopyFrom(fields)
            message.cloud_timestamp.FromNanoseconds(1_700_000_000_000_000_000 + k * 10**9)
            put_message(client, afford_keys.fields, message)
            assert eventually(lambda k=k: len(maps) == k + 1, timeout=90, poll=0.1), (len(maps), k)
        assert eventually(lambda: all(len(live.get(kind, [])) == 2 for kind in keys), timeout=20)
        newest = messages.parse(messages.AffordanceMapMessage, maps[-1].payload.to_bytes())
        for kind in keys:
            assert len(live[kind][-1].attachment.to_bytes()) == 33  # rmw_zenoh drops a sample without it

        # a TRANSIENT_LOCAL subscription as rmw_zenoh declares it, after both maps went out
        for kind, key in keys.items():
            held.append(
                zenoh.ext.declare_advanced_subscriber(
                    client,
                    key,
                    lambda s, kind=kind: late.setdefault(kind, []).append(s),
                    history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                )
            )
        assert eventually(lambda: all(kind in late for kind in keys), timeout=20), late
        time.sleep(0.5)  # nothing more should come: the cache holds the newest map only
        assert all(len(late[kind]) == 1 for kind in keys), {kind: len(v) for kind, v in late.items()}
        places = decode(late["places"][0].payload.to_bytes(), ros_maps.PLACES)
        assert (places.header.stamp.sec, len(places.poses)) == (1_700_000_001, len(newest.skeletons))
        for pose, skeleton in zip(places.poses, newest.skeletons):
            assert (pose.position.x, pose.position.y) == pytest.approx((skeleton.x, skeleton.y), abs=1e-6)
            # the same heading: a quaternion's yaw is in (-pi, pi], a skeleton's theta in [0, 2 pi)
            turn = np.angle(np.exp(1j * (yaw_of(pose.orientation) - skeleton.theta)))
            assert turn == pytest.approx(0.0, abs=1e-6)
        grid = decode(late["confidence"][0].payload.to_bytes(), ros_maps.CONFIDENCE)
        spec = newest.grid
        assert (grid.info.width, grid.info.height) == (spec.nx, spec.ny)
        assert grid.info.resolution == pytest.approx(spec.step)
        confidence = np.frombuffer(newest.confidence, "<f4").reshape(spec.nx, spec.ny)
        cells = np.asarray(grid.data, np.int64).reshape(spec.ny, spec.nx).T
        tried = confidence > LOWEST
        assert ((cells == -1) == ~tried).all()
        order = np.argsort(confidence[tried], kind="stable")
        assert (np.diff(cells[tried][order]) >= 0).all()
        markers = decode(late["markers"][0].payload.to_bytes(), ros_maps.MARKERS).markers
        texts = [m.text for m in markers if m.type == 9]
        expected = [
            f"p {s.probability:.2f}" if s.HasField("probability") else f"{s.score:.2f}"
            for s in newest.skeletons
        ]
        assert texts == (expected or [f"{affordance}: no place found"])
        colour = affordance_colours([m.affordance for m in models])[affordance]
        assert (markers[-1].color.r, markers[-1].color.g) == pytest.approx(colour[:2])
