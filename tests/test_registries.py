"""The three registries (services, learners, sensor-message decoders): every reader takes its list from them,
and an entry added in the one place takes effect everywhere without another edit."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from affordcli.app import app
from affordcore.assembly.assembler import SensorFrame
from affordcore.learn import learners as learner_registry
from affordcore.learn.examples import RoomExamples
from affordcore.learn.fitted import Fitted
from affordcore.learn.learners import LEARNERS, Learner
from affordcore.learn.train import fit
from affordwire import messages, sensors
from affordwire.sensors import SENSOR_DECODERS, decode_sensor
from services.launch import Stack
from services.registry import SERVICES

ROOT = Path(__file__).resolve().parents[1]


def _help(*args: str) -> str:
    result = CliRunner().invoke(app, [*args, "--help"], env={"COLUMNS": "300", "NO_COLOR": "1"})
    assert result.exit_code == 0, result.output
    return re.sub(r"\s+", " ", re.sub(r"[│╭╮╰╯─]", " ", result.output))


# -- services ------------------------------------------------------------------------------------------------


def test_afford_serve_lists_every_registered_service_and_refuses_others():
    text = _help("serve")
    assert all(f"{spec.name} ({spec.summary})" in text for spec in SERVICES.values())
    result = CliRunner().invoke(app, ["serve", "mapper", "--connect", "tcp/127.0.0.1:1", "--robot", "r"])
    assert result.exit_code == 2
    assert f"choose one of {', '.join(SERVICES)}" in result.output


def test_the_launcher_starts_every_registered_service_by_default(tmp_path):
    assert Stack(tmp_path).services == tuple(SERVICES)


def test_every_registered_service_is_documented_and_composed():
    services_doc = (ROOT / "docs" / "services.md").read_text()
    compose = (ROOT / "docker" / "compose.yaml").read_text()
    for name in SERVICES:
        assert f"**{name}**" in services_doc, f"docs/services.md does not describe the {name} service"
        assert f'"serve", "{name}"' in compose, f"docker/compose.yaml does not run the {name} service"


def test_every_registered_service_class_takes_a_node():
    """`afford serve` builds every service as service_class(node) and calls its run(): both signatures must
    fit that call (binding the arguments checks them without starting a service)."""
    for spec in SERVICES.values():
        service_class = spec.service_class()
        constructor = inspect.signature(service_class)
        assert list(constructor.parameters)[:1] == ["node"], f"{spec.target}{constructor}"
        constructor.bind(object())  # TypeError: a constructor that wants more than the node
        assert callable(getattr(service_class, "run", None)), f"{spec.target} has no run()"
        inspect.signature(service_class.run).bind(object())  # run(self) and nothing more


# -- learners ------------------------------------------------------------------------------------------------


def test_the_cli_offers_every_registered_learner():
    assert all(name in _help("train") for name in LEARNERS)
    assert ",".join(LEARNERS) in _help("evaluate")  # the default: every learner


def test_every_registered_learner_is_documented():
    learning = (ROOT / "docs" / "learning.md").read_text()
    readme = (ROOT / "README.md").read_text()
    for name in LEARNERS:
        assert f"| `{name}` |" in learning, f"docs/learning.md's learner table lacks {name}"
        assert name in readme, f"README.md does not name the learner {name}"


def test_a_learner_added_to_the_registry_trains_with_no_other_change(monkeypatch):
    def mean_difference(train, validation, params, rng):
        positive, negative = train.X[train.y > 0].mean(axis=0), train.X[train.y <= 0].mean(axis=0)
        return Fitted(positive - negative, 0.0, params.get("threshold", 0.0), {"rule": "mean difference"})

    monkeypatch.setitem(
        LEARNERS, "mean-difference", Learner("mean-difference", "a test learner", mean_difference)
    )
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 4)).astype(np.float32)
    y = np.where(np.arange(200) < 20, 1, -1)
    X[y > 0] += 2.0
    examples = RoomExamples("room", X, y)
    fitted = fit("mean-difference", examples, examples, {"threshold": 0.5}, seed=0)
    np.testing.assert_allclose(fitted.weights, X[:20].mean(axis=0) - X[20:].mean(axis=0), rtol=1e-5)
    assert (fitted.threshold, fitted.report) == (0.5, {"rule": "mean difference"})


def test_an_unknown_learner_names_the_registered_ones():
    with pytest.raises(ValueError, match=", ".join(LEARNERS)):
        learner_registry.get_learner("svm-light")


# -- sensor-message decoders ---------------------------------------------------------------------------------


def test_every_registered_sensor_message_is_documented():
    services_doc = (ROOT / "docs" / "services.md").read_text()
    for schema in SENSOR_DECODERS:
        assert f"`{schema.split('.')[-1]}`" in services_doc, f"docs/services.md does not describe {schema}"


def test_a_sensor_decoder_added_to_the_registry_is_taken_by_schema(monkeypatch):
    def xyz_text(payload: bytes, limits) -> SensorFrame:
        return SensorFrame(
            frame_id="text", stamp=1.5, points=np.loadtxt(payload.decode().splitlines()).reshape(-1, 3)
        )

    monkeypatch.setitem(SENSOR_DECODERS, "example.XyzText", xyz_text)
    frame = decode_sensor("example.XyzText", b"0 0 1\n1 2 3\n")
    np.testing.assert_allclose(frame.points, [[0, 0, 1], [1, 2, 3]])
    # the refusal lists it among the known
    with pytest.raises(messages.MessageError, match="example.XyzText"):
        decode_sensor("example.Other", b"")


def test_the_registered_decoders_read_scans_and_depth_frames():
    scan = messages.Scan(frame_id="lidar")
    messages.pack_points(scan, np.array([[1.0, 2.0, 3.0]]))
    messages.stamp(scan.timestamp, 12.5)
    messages.set_vector(scan.gravity, [0, 0, -2])
    frame = sensors.decode_sensor(messages.schema_name(messages.Scan), scan.SerializeToString())
    assert (frame.frame_id, frame.stamp, frame.depth, frame.pose_guess) == ("lidar", 12.5, None, None)
    np.testing.assert_allclose(frame.points, [[1, 2, 3]])
    np.testing.assert_allclose(frame.gravity, [0, 0, -1])

    depth = np.full((4, 6), 1500, dtype=np.uint16)
    camera = messages.depth_frame_message(
        depth, np.array([[500.0, 0, 3], [0, 500, 2], [0, 0, 1]]), frame_id="cam"
    )
    frame = sensors.decode_sensor(messages.schema_name(messages.DepthFrame), camera.SerializeToString())
    assert frame.points is None and frame.frame_id == "cam"
    np.testing.assert_array_equal(frame.depth.pixels, depth)
