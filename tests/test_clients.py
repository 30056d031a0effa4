"""A client in any language needs only schemas/ and docs/clients.md: the minimal Python client
(docs/clients/minimal_client.py, listed whole in docs/clients.md) imports nothing of affordmap, runs on Python
generated from schemas/ by protoc, and against a running stack gets the maps of its own cloud, sent in a frame
of its own (the features service levels it), or the refusal of it."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
CLIENT = ROOT / "docs" / "clients" / "minimal_client.py"
DOC = ROOT / "docs" / "clients.md"
PROTOS = sorted((ROOT / "schemas" / "afford" / "v1").glob("*.proto"))
SHIPPED = ("sitting-relaxing", "sitting-working", "standing-working")
GENERATED = {f"{proto.stem}_pb2" for proto in PROTOS}
# map frame of the test's cloud: y up (world z), the floor at y = +0.8, shifted 2 m along x
MAP_FROM_WORLD = np.array([[1.0, 0, 0, 2.0], [0, 0, 1, 0.8], [0, -1, 0, 0], [0, 0, 0, 1]])


# -- what the client imports ---------------------------------------------------------------------------------


def foreign_imports(source: str) -> list[str]:
    """The modules `source` imports beyond the standard library, numpy, zenoh, google.protobuf and the code
    protoc generates from schemas/ (afford.v1.<file>_pb2), and any dynamic import."""
    allowed_roots = set(sys.stdlib_module_names) | {"numpy", "zenoh"}
    wrong = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                wrong.append(f"relative import from {'.' * node.level}{node.module or ''}")
                continue
            modules = [node.module]
            if node.module == "afford.v1":
                modules = [f"afford.v1.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) in {
            "__import__",
            "import_module",
        }:
            wrong.append("a dynamic import")
            continue
        else:
            continue
        for module in modules:
            root = module.split(".")[0]
            generated = module.startswith("afford.v1.") and module.split(".", 2)[2] in GENERATED
            if not (root in allowed_roots or module.startswith("google.protobuf") or generated):
                wrong.append(module)
    return wrong


def test_the_minimal_client_imports_only_zenoh_protobuf_numpy_and_generated_code():
    source = CLIENT.read_text()
    assert foreign_imports(source) == []
    tree = ast.parse(source)
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert {"zenoh", "numpy", "afford.v1"} <= imported


@pytest.mark.parametrize(
    "line",
    [
        "from affordwire import messages",
        "import affordcore.geometry.skeleton",
        "from services.transport import Keys",
        "import affordcli.app",
        "from afford import v1",
        "from afford.v1 import not_generated_pb2",
        "from .proto import maps_pb2",
        "import rerun",
        "importlib.import_module('affordwire')",
        "__import__('services')",
    ],
)
def test_the_import_check_catches_what_a_client_must_not_import(line):
    assert foreign_imports(CLIENT.read_text() + "\n" + line + "\n") != []


def test_docs_clients_md_lists_the_client_file_exactly():
    """The listing in the doc is the file the tests run, character for character."""
    text = DOC.read_text()
    assert "(clients/minimal_client.py)" in text  # linked
    blocks = re.findall(r"^```python\n(.*?)^```$", text, re.MULTILINE | re.DOTALL)
    listings = [block for block in blocks if "def main() -> int:" in block]
    assert len(listings) == 1, "docs/clients.md must list the minimal client once"
    assert listings[0] == CLIENT.read_text()


def test_docs_clients_md_names_the_joints_in_order():
    from affordcore.geometry.skeleton import JOINTS

    numbered = ", ".join(f"{index} {name}" for index, name in enumerate(JOINTS))
    assert numbered in re.sub(r"\s*\n\s*", " ", DOC.read_text())  # lines joined up


# -- the client against generated code -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> Path:
    """Python generated from schemas/ by grpcio-tools' protoc, with the command docs/clients.md gives."""
    pytest.importorskip("grpc_tools", reason="grpcio-tools (a test dependency) bundles protoc")
    out = tmp_path_factory.mktemp("generated")
    result = subprocess.run(
        [sys.executable, "-m", "grpc_tools.protoc", "-I", str(ROOT / "schemas"), f"--python_out={out}"]
        + [str(proto) for proto in PROTOS],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.stem for p in (out / "afford" / "v1").glob("*_pb2.py")) == sorted(GENERATED)
    return out


def _env(generated: Path, *extra: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(map(str, [generated, *extra]))}


SIDE_BY_SIDE = """
import json, sys
from pathlib import Path
import numpy as np
from afford.v1 import maps_pb2 as client_maps  # the client's code, generated from schemas/
import affordcli.app
import affordwire
from affordwire import messages
from affordwire.proto import maps_pb2 as wire_maps

points = np.random.default_rng(3).uniform(-3, 3, (150, 3)).astype(np.float32).astype(np.float64)
ours = messages.cloud_message(points, np.eye(4), source="side-by-side", frames=3, at=12.5, scans_received=4)
theirs = client_maps.Cloud.FromString(ours.SerializeToString())  # a map Cloud, as a client reads it
theirs.source = "client"  # and one the client sends back
back = messages.parse(messages.CloudMessage, theirs.SerializeToString())
print(json.dumps({
    "path0": sys.path[0],
    "client": client_maps.__file__,
    "cli": affordcli.app.__file__,
    "wire": [affordwire.__file__, wire_maps.__file__],
    "names": [client_maps.Cloud.DESCRIPTOR.full_name, messages.schema_name(ours)],
    "same_bytes": theirs.SerializeToString() == back.SerializeToString(),
    "read": [theirs.frames, theirs.scans_received, back.source],
    "points": bool(np.array_equal(messages.cloud_points(back), points)),
}))
"""


def test_a_python_client_imports_its_generated_code_beside_affordmap_from_the_project_root(generated):
    """protoc generates the schemas as the Python package `afford.v1`, which the project leaves to
    clients (its command line is `affordcli`). In the project's root, where the project's packages come first
    on sys.path (`python -c`, `python -m`), one process imports the client's generated code, affordwire and
    the command line, and a Cloud passes between the client's class and affordwire's with the same bytes."""
    result = subprocess.run(
        [sys.executable, "-c", SIDE_BY_SIDE],
        cwd=ROOT,
        env=_env(generated),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    assert found["path0"] == ""  # the project's root (the working directory) is searched first
    assert Path(found["client"]).is_relative_to(generated)
    assert Path(found["cli"]).is_relative_to(ROOT / "affordcli")
    assert all(Path(file).is_relative_to(ROOT / "affordwire") for file in found["wire"])
    assert found["names"] == ["afford.v1.Cloud", "afford.v1.Cloud"]
    assert found["same_bytes"]
    assert found["read"] == [3, 4, "client"] and found["points"]


def test_the_client_reads_ply_and_xyz_files(generated, tmp_path):
    """Its PLY reader (ascii and binary, extra vertex properties) and XYZ reader give the points back."""
    import plyfile

    from affordcore.geometry.scene import Cloud, save_cloud

    rng = np.random.default_rng(5)
    points = rng.uniform(-5, 5, size=(300, 3)).astype(np.float32)
    save_cloud(tmp_path / "binary.ply", Cloud(points.astype(np.float64), rng.random((300, 3))))
    vertices = np.zeros(300, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("intensity", "u2")])
    for index, axis in enumerate("xyz"):
        vertices[axis] = points[:, index]
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    plyfile.PlyData(
        [plyfile.PlyElement.describe(vertices, "vertex"), plyfile.PlyElement.describe(faces, "face")],
        text=True,
    ).write(str(tmp_path / "ascii.ply"))
    plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")], byte_order=">").write(
        str(tmp_path / "big.ply")
    )
    np.savetxt(tmp_path / "points.xyz", np.hstack([points, np.ones((300, 1))]), fmt="%.9g")
    script = (
        "import sys, numpy as np; from pathlib import Path; import minimal_client as c\n"
        "for name in sys.argv[1:]:\n"
        "    np.save(name + '.npy', c.read_points(Path(name)))\n"
    )
    names = [str(tmp_path / name) for name in ("binary.ply", "ascii.ply", "big.ply", "points.xyz")]
    result = subprocess.run(
        [sys.executable, "-c", script, *names],
        cwd=tmp_path,
        env=_env(generated, CLIENT.parent),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    for name in names:
        read = np.load(name + ".npy")
        assert read.shape == (300, 3), name
        if name.endswith(".ply"):
            assert np.array_equal(read, points.astype(np.float64)), name  # float32 and float64 exactly
        else:
            assert np.array_equal(read.astype(np.float32), points), name  # decimal text, 9 digits


def _run_client(generated: Path, cwd: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """The client as a user runs it: its own process, only the generated code on PYTHONPATH."""
    return subprocess.run(
        [sys.executable, str(CLIENT), *args],
        cwd=cwd,
        env=_env(generated),
        capture_output=True,
        text=True,
        timeout=timeout + 60,
    )


PLACE = re.compile(
    r"place \d+: score (?P<score>\S+), facing \S+ deg, torso world \((?P<world>[^)]*)\), "
    r"(?P<frame>\w+) \((?P<mine>[^)]*)\)"
)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    from services.launch import Stack

    stack = Stack(tmp_path_factory.mktemp("stack"), robot="anyclient").start()
    yield stack
    codes = stack.stop()
    assert set(codes.values()) == {0}, stack.logs()


@pytest.mark.slow
def test_the_minimal_client_gets_the_maps_of_its_own_unlevelled_cloud(generated, stack, tmp_path):
    """The example room in a frame of the client's own (y up, floor at y = +0.8, sent as frame "map"): one map
    per shipped affordance answers it, and the sofa's places, brought back into the client's frame with the
    maps' world_from_input, lie on the sofa."""
    from affordcore.example import example_room
    from affordcore.geometry.scene import Cloud, save_cloud

    room = example_room()
    in_map = room.points @ MAP_FROM_WORLD[:3, :3].T + MAP_FROM_WORLD[:3, 3]
    save_cloud(tmp_path / "room.ply", Cloud(in_map, room.colors))
    result = _run_client(
        generated, tmp_path, "room.ply", "--connect", stack.endpoint, "--robot", stack.robot, "--frame", "map"
    )
    assert result.returncode == 0, result.stdout + result.stderr + stack.logs()
    headers = re.findall(r"^(\S+): (\d+) places", result.stdout, re.MULTILINE)
    assert sorted(name for name, _ in headers) == sorted(SHIPPED), result.stdout
    places = {name: int(count) for name, count in headers}
    assert places["sitting-relaxing"] >= 1, result.stdout  # never empty maps for an unlevelled room

    lines = result.stdout.split("sitting-relaxing:", 1)[1].split("\n")[1 : 1 + places["sitting-relaxing"]]
    world_from_map = np.linalg.inv(MAP_FROM_WORLD)
    for line in lines:
        match = PLACE.search(line)
        assert match and match["frame"] == "map", line
        mine = np.array([float(v) for v in match["mine"].split(",")])
        x, y, z = world_from_map[:3, :3] @ mine + world_from_map[:3, 3]  # the room's own coordinates
        # the sofa: seat 0.05 .. 0.95 m from the west wall, 1.2 .. 3.2 m along it, seat top 0.42 m
        assert 0.0 <= x <= 1.4 and 1.0 <= y <= 3.4 and 0.3 <= z <= 1.0, (line, (x, y, z))


@pytest.mark.slow
def test_the_minimal_client_exits_non_zero_when_its_cloud_is_refused(generated, stack, tmp_path):
    """Points with no floor (a cloud of points in a ball): the features service refuses the cloud on its
    error key with the cloud's timestamp, and the client says why and exits 1 (no waiting for the timeout)."""
    rng = np.random.default_rng(1)
    ball = rng.normal(size=(5000, 3))
    np.savetxt(tmp_path / "ball.xyz", ball / np.linalg.norm(ball, axis=1, keepdims=True), fmt="%.6f")
    result = _run_client(
        generated,
        tmp_path,
        "ball.xyz",
        "--connect",
        stack.endpoint,
        "--robot",
        stack.robot,
        "--timeout",
        "120",
    )
    assert result.returncode == 1, result.stdout + result.stderr + stack.logs()
    assert "refused by features: no floor found" in result.stderr
    assert "places" not in result.stdout  # no maps of it


@pytest.mark.slow
def test_the_minimal_client_times_out_when_no_service_listens(generated, stack, tmp_path):
    result = _run_client(
        generated, tmp_path, "--connect", stack.endpoint, "--robot", "nobody", "--timeout", "3", timeout=3
    )
    assert result.returncode == 3, result.stdout + result.stderr
    assert "nothing subscribes to afford/@v1/nobody/map/cloud" in result.stderr
