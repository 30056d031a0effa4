"""The afford.v1 Protocol Buffers: the checked-in generated code matches schemas/afford/v1, and the messages
carry the fields the design names (checked through the descriptors of the generated code)."""

from __future__ import annotations

import importlib.util
import re
import shutil
import sys
from pathlib import Path

import pytest

from affordwire.proto import geometry_pb2, maps_pb2, sensing_pb2, service_pb2

ROOT = Path(__file__).resolve().parents[1]
PROTOS = ROOT / "schemas" / "afford" / "v1"
GENERATED = ROOT / "affordwire" / "proto"
MODULES = {"geometry": geometry_pb2, "maps": maps_pb2, "sensing": sensing_pb2, "service": service_pb2}

F = geometry_pb2.Pose.DESCRIPTOR.fields_by_name["frame_id"]  # any field: for the type constants
STRING, BYTES, DOUBLE, UINT32, UINT64, MESSAGE, ENUM, FLOAT = (
    F.TYPE_STRING,
    F.TYPE_BYTES,
    F.TYPE_DOUBLE,
    F.TYPE_UINT32,
    F.TYPE_UINT64,
    F.TYPE_MESSAGE,
    F.TYPE_ENUM,
    F.TYPE_FLOAT,
)
TIMESTAMP = "google.protobuf.Timestamp"


@pytest.fixture(scope="module")
def generator():
    """schemas/generate.py loaded as a module (it is a script, not part of a package)."""
    pytest.importorskip(
        "grpc_tools", reason="grpcio-tools (a test dependency) bundles the protoc the schemas need"
    )
    spec = importlib.util.spec_from_file_location("afford_schemas_generate", ROOT / "schemas" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def generated(generator) -> dict[str, str]:
    return generator.generate()


# -- the generated code is current ---------------------------------------------------------------------------


def test_checked_in_code_is_what_protoc_generates_now(generator, generated):
    stems = sorted(p.stem for p in PROTOS.glob("*.proto"))
    assert stems == sorted(MODULES)
    assert sorted(generated) == sorted(f"{stem}_pb2{suffix}" for stem in stems for suffix in (".py", ".pyi"))
    assert generator.stale(generated) == [], "run: python schemas/generate.py"


def test_generated_modules_import_each_other_relatively(generated):
    """protoc writes `from afford.v1 import x_pb2`; the generator rewrites it so the code lives in
    affordwire.proto."""
    for name, text in generated.items():
        assert "from afford.v1 import" not in text, name
    assert re.search(r"^from \. import geometry_pb2", generated["maps_pb2.py"], re.MULTILINE)
    assert re.search(r"^from \. import geometry_pb2", generated["sensing_pb2.py"], re.MULTILINE)


@pytest.fixture
def proto_copy(generator, tmp_path, monkeypatch) -> Path:
    """A copy of affordwire/proto that the generator checks against instead of the real one."""
    copy = tmp_path / "proto"
    shutil.copytree(GENERATED, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(generator, "PACKAGE", copy)
    return copy


def test_stale_reports_an_edited_generated_file(generator, generated, proto_copy):
    assert generator.stale(generated) == []
    path = proto_copy / "sensing_pb2.py"
    path.write_text(path.read_text().replace("_globals", "_globals ", 1))  # one character differs
    assert generator.stale(generated) == ["sensing_pb2.py"]
    stub = proto_copy / "maps_pb2.pyi"
    stub.write_text(stub.read_text() + "\n")
    assert generator.stale(generated) == ["maps_pb2.pyi", "sensing_pb2.py"]


def test_stale_reports_missing_and_extra_generated_files(generator, generated, proto_copy):
    (proto_copy / "service_pb2.py").unlink()
    (proto_copy / "old_pb2.py").write_text("# from a .proto that was removed\n")
    (proto_copy / "notes.txt").write_text("not generated code\n")  # not a *_pb2 file: none of its business
    assert generator.stale(generated) == ["old_pb2.py", "service_pb2.py"]


def test_stale_reports_a_proto_edit(generator, generated, proto_copy, tmp_path, monkeypatch):
    """Editing a .proto without regenerating is what the check is for."""
    schemas = tmp_path / "schemas"
    shutil.copytree(ROOT / "schemas" / "afford", schemas / "afford")
    path = schemas / "afford" / "v1" / "service.proto"
    path.write_text(
        path.read_text().replace("string version = 10;", "string version = 10;\n  string host = 99;")
    )
    monkeypatch.setattr(generator, "SCHEMAS", schemas)
    assert generator.stale(generator.generate()) == ["service_pb2.py", "service_pb2.pyi"]


def test_main_check_exit_code_and_rewrite(generator, generated, proto_copy, tmp_path, monkeypatch, capsys):
    # main() reports where it wrote relative to the repository
    monkeypatch.setattr(generator, "ROOT", tmp_path)
    monkeypatch.setattr(sys, "argv", ["generate.py", "--check"])
    assert generator.main() == 0
    (proto_copy / "geometry_pb2.py").write_text("stale\n")
    assert generator.main() == 1
    assert "geometry_pb2.py" in capsys.readouterr().err
    monkeypatch.setattr(sys, "argv", ["generate.py"])  # regenerate into the copy
    assert generator.main() == 0
    assert f"wrote {len(generated)} files" in capsys.readouterr().out
    assert (proto_copy / "geometry_pb2.py").read_text() == generated["geometry_pb2.py"]
    assert generator.stale(generated) == []


# -- every .proto is in afford.v1 ----------------------------------------------------------------------------


@pytest.mark.parametrize("stem", sorted(MODULES))
def test_every_proto_declares_package_afford_v1(stem):
    text = (PROTOS / f"{stem}.proto").read_text()
    assert re.findall(r"^\s*package\s+([\w.]+)\s*;", text, re.MULTILINE) == ["afford.v1"]
    assert re.search(r'^\s*syntax\s*=\s*"proto3"\s*;', text, re.MULTILINE)
    descriptor = MODULES[stem].DESCRIPTOR
    assert descriptor.package == "afford.v1" and descriptor.name == f"afford/v1/{stem}.proto"
    for message in descriptor.message_types_by_name.values():
        assert message.full_name == f"afford.v1.{message.name}"


# -- self-contained: a client in any language needs only these files ---------------------------------------


@pytest.mark.parametrize("stem", sorted(MODULES))
def test_every_proto_sets_the_package_options_of_other_languages(stem):
    text = (PROTOS / f"{stem}.proto").read_text()
    assert re.findall(r"^option (\w+) = ", text, re.MULTILINE) == [
        "csharp_namespace",
        "go_package",
        "java_multiple_files",
        "java_outer_classname",
        "java_package",
    ]
    options = MODULES[stem].DESCRIPTOR.GetOptions()  # as protoc read them
    assert options.java_package == "affordmap.afford.v1" and options.java_multiple_files
    assert options.java_outer_classname == f"{stem.capitalize()}Proto"  # never a message's name
    assert options.go_package == "affordmap/afford/v1;affordv1"
    assert options.csharp_namespace == "Affordmap.Afford.V1"
    assert options.java_outer_classname not in MODULES[stem].DESCRIPTOR.message_types_by_name


def _comments(stem: str) -> str:
    """The comments of a .proto, joined into one line of text."""
    text = (PROTOS / f"{stem}.proto").read_text()
    return " ".join(" ".join(re.findall(r"//[ \t]*(.*)$", text, re.MULTILINE)).split())


def test_the_protos_refer_to_nothing_outside_them():
    for stem in MODULES:
        text = (PROTOS / f"{stem}.proto").read_text()
        assert "DESIGN.md" not in text, f"{stem}.proto refers to DESIGN.md, which is not in the repository"


def test_maps_proto_states_the_joint_order_of_the_skeletons():
    from affordcore.geometry.skeleton import JOINTS

    numbered = ", ".join(f"{index} {name}" for index, name in enumerate(JOINTS))
    assert numbered in _comments("maps")
    assert "15 joints x (x, y, z) = 45 floats" in _comments("maps")


def test_geometry_proto_states_the_units_and_frames():
    comments = _comments("geometry")
    for convention in (
        "Units: metres, seconds, radians",
        "little-endian",
        "z up, with the floor at z = 0",
        "(parent_from_child)",
        "a Pose left unset (all zero, quaternion included) is the identity",
        "counter-clockwise from world +x",
        '"application/protobuf;afford.v1.Cloud"',
        "congestion control BLOCK",
    ):
        assert convention in comments, convention


# -- the messages of the design ------------------------------------------------------------------------------

# {message: {field: (type, message or enum full name, repeated)}}
POINTS = {
    "timestamp": (MESSAGE, TIMESTAMP, False),
    "frame_id": (STRING, None, False),
    "fields": (MESSAGE, "afford.v1.PackedElementField", True),
    "point_stride": (UINT32, None, False),
    "data": (BYTES, None, False),
}
SOURCE = {
    "world_from_input": (MESSAGE, "afford.v1.Pose", False),
    "cloud_timestamp": (MESSAGE, TIMESTAMP, False),
    "frames": (UINT32, None, False),
}
DESIGN = {
    sensing_pb2.Scan: {**POINTS, "pose_guess": (MESSAGE, "afford.v1.Pose", False)},
    sensing_pb2.DepthFrame: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "frame_id": (STRING, None, False),
        "width": (UINT32, None, False),
        "height": (UINT32, None, False),
        "depth": (BYTES, None, False),
        "depth_scale": (DOUBLE, None, False),
        "invalid_value": (UINT32, None, False),
        "intrinsics": (MESSAGE, "afford.v1.CameraIntrinsics", False),
        "pose_guess": (MESSAGE, "afford.v1.Pose", False),
    },
    sensing_pb2.CameraIntrinsics: {name: (DOUBLE, None, False) for name in ("fx", "fy", "cx", "cy")},
    maps_pb2.Cloud: {
        **POINTS,
        "world_from_input": (MESSAGE, "afford.v1.Pose", False),
        "frames": (UINT32, None, False),
        "source": (STRING, None, False),
    },
    geometry_pb2.Pose: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "frame_id": (STRING, None, False),
        "child_frame_id": (STRING, None, False),
        "position": (MESSAGE, "afford.v1.Vector3", False),
        "orientation": (MESSAGE, "afford.v1.Quaternion", False),
    },
    geometry_pb2.Vector3: {name: (DOUBLE, None, False) for name in "xyz"},
    geometry_pb2.Quaternion: {name: (DOUBLE, None, False) for name in "xyzw"},
    geometry_pb2.PackedElementField: {
        "name": (STRING, None, False),
        "offset": (UINT32, None, False),
        "type": (ENUM, "afford.v1.PackedElementField.NumericType", False),
    },
    maps_pb2.SceneFields: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "frame_id": (STRING, None, False),
        "grid": (MESSAGE, "afford.v1.VoxelGrid", False),
        "occupancy": (BYTES, None, False),
        "distance": (BYTES, None, False),
        "normals": (BYTES, None, False),
        **{name: (DOUBLE, None, False) for name in ("x_min", "y_min", "x_max", "y_max")},
        **SOURCE,
    },
    maps_pb2.VoxelGrid: {
        "origin": (MESSAGE, "afford.v1.Vector3", False),
        "resolution": (DOUBLE, None, False),
        **{name: (UINT32, None, False) for name in ("nx", "ny", "nz")},
    },
    maps_pb2.AffordanceMap: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "frame_id": (STRING, None, False),
        "affordance": (STRING, None, False),
        "model": (STRING, None, False),
        "threshold": (DOUBLE, None, False),
        "grid": (MESSAGE, "afford.v1.PoseGridSpec", False),
        "skeletons": (MESSAGE, "afford.v1.PlacedSkeleton", True),
        "positives": (BYTES, None, False),
        "confidence": (BYTES, None, False),
        **SOURCE,
    },
    maps_pb2.PoseGridSpec: {
        "x0": (DOUBLE, None, False),
        "y0": (DOUBLE, None, False),
        "step": (DOUBLE, None, False),
        "nx": (UINT32, None, False),
        "ny": (UINT32, None, False),
        "z": (DOUBLE, None, True),
        "theta_step": (DOUBLE, None, False),
        "n_theta": (UINT32, None, False),
    },
    maps_pb2.PlacedSkeleton: {
        **{name: (DOUBLE, None, False) for name in ("x", "y", "z", "theta", "score")},
        "joints": (FLOAT, None, True),
    },
    service_pb2.Status: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "service": (STRING, None, False),
        "robot": (STRING, None, False),
        "state": (ENUM, "afford.v1.Status.State", False),
        "detail": (STRING, None, False),
        **{name: (UINT64, None, False) for name in ("accepted", "rejected", "published")},
        "last_seconds": (DOUBLE, None, False),
        "version": (STRING, None, False),
    },
    service_pb2.Error: {
        "timestamp": (MESSAGE, TIMESTAMP, False),
        "service": (STRING, None, False),
        "key": (STRING, None, False),
        "encoding": (STRING, None, False),
        "payload_bytes": (UINT64, None, False),
        "reason": (STRING, None, False),
        "input_timestamp": (MESSAGE, TIMESTAMP, False),  # how a client knows a refusal answers its cloud
    },
}


@pytest.mark.parametrize("message", DESIGN, ids=lambda m: m.DESCRIPTOR.name)
def test_message_has_the_fields_of_the_design(message):
    descriptor = message.DESCRIPTOR
    fields = descriptor.fields_by_name
    missing = sorted(set(DESIGN[message]) - set(fields))
    assert not missing, f"{descriptor.full_name} lacks {missing}"
    for name, (kind, type_name, repeated) in DESIGN[message].items():
        field = fields[name]
        assert field.type == kind, f"{descriptor.full_name}.{name}"
        assert field.is_repeated == repeated, f"{descriptor.full_name}.{name}"
        if kind == MESSAGE:
            assert field.message_type.full_name == type_name, f"{descriptor.full_name}.{name}"
        if kind == ENUM:
            assert field.enum_type.full_name == type_name, f"{descriptor.full_name}.{name}"
    numbers = [field.number for field in descriptor.fields]
    assert len(set(numbers)) == len(numbers)


@pytest.mark.parametrize(
    "message", [sensing_pb2.Scan, sensing_pb2.DepthFrame], ids=lambda m: m.DESCRIPTOR.name
)
def test_pose_guess_is_optional(message):
    """`optional Pose pose_guess`: a robot without other odometry leaves it out, and a reader can tell."""
    field = message.DESCRIPTOR.fields_by_name["pose_guess"]
    assert (
        field.has_presence
        and field.containing_oneof is not None
        and field.containing_oneof.name == "_pose_guess"
    )
    scan = message()
    assert not scan.HasField("pose_guess")
    scan.pose_guess.frame_id = "world"
    again = message.FromString(scan.SerializeToString())
    assert again.HasField("pose_guess") and again.pose_guess.frame_id == "world"


def test_packed_field_types_and_status_states():
    numeric = geometry_pb2.PackedElementField.NumericType
    assert {name: numeric.Value(name) for name in numeric.keys()} == {
        "UNKNOWN": 0,
        "UINT8": 1,
        "INT8": 2,
        "UINT16": 3,
        "INT16": 4,
        "UINT32": 5,
        "INT32": 6,
        "FLOAT32": 7,
        "FLOAT64": 8,
    }
    state = service_pb2.Status.State
    assert (
        set(state.keys()) == {"UNKNOWN", "STARTING", "READY", "BUSY", "STOPPING"}
        and state.Value("UNKNOWN") == 0
    )


def test_a_depth_frame_serialises_16_bit_depth_with_its_scale_and_intrinsics():
    frame = sensing_pb2.DepthFrame(
        width=2,
        height=1,
        depth=(1234).to_bytes(2, "little") + (65535).to_bytes(2, "little"),
        depth_scale=0.001,
        invalid_value=65535,
    )
    frame.intrinsics.fx, frame.intrinsics.fy, frame.intrinsics.cx, frame.intrinsics.cy = (
        585.0,
        586.0,
        320.5,
        240.25,
    )
    again = sensing_pb2.DepthFrame.FromString(frame.SerializeToString())
    assert again == frame and again.depth == frame.depth and again.depth_scale == 0.001
    assert (again.intrinsics.fx, again.intrinsics.fy, again.intrinsics.cx, again.intrinsics.cy) == (
        585.0,
        586.0,
        320.5,
        240.25,
    )
