"""One identity per robot: on a site made with `afford certs --sensor NAME@ROBOT` (and
`--robot ROBOT`), a robot's sensor and services write only that robot's keys, whatever certificate the
rest of the site holds.

Two robots share one router on loopback: robot B runs its three services as `assembler@robotB`, ...; robot
A runs its assembler as `assembler@robotA`. Robot A's sensor is refused on robot B's scan key (robot B's
assembler never hears of it), while the same sensor's scan on robot A's key is taken by robot A's assembler
and robot B's own sensor's by robot B's: the refusal is the ACL's, not a dead service.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from conftest import eventually

from services.launch import Stack
from services.security import Site, write_site
from services.transport import Keys

A, B = Keys("robotA"), Keys("robotB")


def test_bound_identities_write_only_their_robots_keys():
    site = Site(sensors=["cam@robotA", "robot"], mappers=["room@robotB"], robots=["robotC"])
    writes = site.writes()
    assert writes["cam@robotA"] == ["afford/@v1/robotA/scan/**"]
    assert writes["room@robotB"] == ["afford/@v1/robotB/map/cloud"]
    assert writes["robot"] == ["afford/@v1/*/scan/**"]  # a plain name: every robot, as before
    # robots given and robots a sensor or mapper names get their own services, bound likewise
    assert site.robot_names() == ["robotC", "robotA", "robotB"]
    for robot in ("robotA", "robotB", "robotC"):
        assert writes[f"assembler@{robot}"] == [
            f"afford/@v1/{robot}/{key}"
            for key in ("map/cloud", "map/pose", "status/assembler", "error/assembler")
        ]
        assert all(key.startswith(f"afford/@v1/{robot}/") for key in writes[f"inference@{robot}"])
    # the site-wide services stay (single-robot sites, sharded inference workers serving many robots)
    assert writes["assembler"][0] == "afford/@v1/*/map/cloud"
    assert "afford/@v1/@workers/inference-$*/**" in writes["inference"]


@pytest.mark.parametrize(
    "options, message",
    [
        (["--sensor", "cam@"], "robot ''"),
        (["--sensor", "@robotA"], "name ''"),
        (["--sensor", "cam@robot/A"], "robot 'robot/A'"),
        (["--viewer", "screen@robotA"], "a viewer reads every robot"),
        (["--robot", "robot A"], "robot name 'robot A'"),
        (["--sensor", "cam@robotA", "--mapper", "cam@robotA"], "unique"),
    ],
)
def test_afford_certs_names_what_is_wrong_with_a_bound_identity(tmp_path, options, message):
    out = tmp_path / "site"
    bad = subprocess.run(
        [sys.executable, "-m", "affordcli", "certs", str(out), *options],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and message in bad.stderr, bad.stderr
    assert not out.exists()  # nothing half-written


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    folder = tmp_path_factory.mktemp("robots")
    write_site(Site(sensors=["cam@robotA", "cam@robotB"], viewers=["viewer"]), folder)
    return folder


@pytest.fixture(scope="module")
def robots(site, tmp_path_factory):
    """Robot B's three services with the router, then robot A's assembler on the same router."""
    robot_b = Stack(tmp_path_factory.mktemp("robotB"), robot="robotB", site=site).start()
    robot_a = Stack(
        tmp_path_factory.mktemp("robotA"),
        robot="robotA",
        site=site,
        services=("assembler",),
        listen=robot_b.listen,
    )
    try:
        robot_a.start(router=False)
    except Exception:
        robot_b.stop()
        raise
    yield robot_a, robot_b
    codes = {**robot_a.stop(), **robot_b.stop()}
    assert all(code == 0 for code in codes.values()), (codes, robot_a.logs(), robot_b.logs())


@pytest.mark.slow
def test_each_robot_runs_its_services_as_its_own_identities(robots):
    robot_a, robot_b = robots
    assert robot_b.config("assembler").endswith("assembler@robotB.json5")
    assert robot_a.config("assembler").endswith("assembler@robotA.json5")
    assert robot_b.config("viewer").endswith("/viewer.json5")  # no robot's own: the site-wide one


@pytest.mark.slow
def test_a_sensor_of_robot_a_is_refused_on_robot_b_keys(robots):
    from affordwire import messages

    robot_a, robot_b = robots
    viewer, cam_a, cam_b = (
        robot_b.session(wait=10, identity=name) for name in ("viewer", "cam@robotA", "cam@robotB")
    )
    scans: list[str] = []
    heard: dict[str, list[str]] = {"robotA": [], "robotB": []}  # the inputs each robot's assembler refused

    def on_sample(sample) -> None:
        key = str(sample.key_expr)
        if "/scan/" in key:
            scans.append(key)
        elif key.endswith("/error/assembler"):
            heard[key.split("/")[2]].append(messages.Error.FromString(sample.payload.to_bytes()).key)

    subscriber = viewer.declare_subscriber("afford/@v1/**", on_sample)
    try:
        time.sleep(1.0)  # the subscriber's declaration reaches the router
        # bytes that are not a scan: an assembler that takes them answers on its error key with the input's
        # key, so the error keys show which scans reached which assembler
        cam_a.put(B.scan("cam"), b"robot A's sensor on robot B's key")
        cam_a.put(A.scan("cam"), b"robot A's sensor on its own key")
        cam_b.put(B.scan("cam2"), b"robot B's sensor on its own key")
        # the positive controls: robot A's assembler took its sensor's scan, robot B's its own sensor's
        assert eventually(lambda: heard["robotA"] and heard["robotB"], timeout=15), (heard, robot_a.logs())
        time.sleep(1.0)  # anything wrongly let through would have arrived by now
    finally:
        subscriber.undeclare()
        for session in (viewer, cam_a, cam_b):
            session.close()
    assert heard == {"robotA": [A.scan("cam")], "robotB": [B.scan("cam2")]}
    assert B.scan("cam") not in scans and A.scan("cam") in scans  # the router dropped it for everyone


@pytest.mark.slow
def test_robot_a_services_write_only_robot_a_keys(robots):
    robot_a, robot_b = robots
    names = ("viewer", "assembler@robotA", "features@robotA", "inference@robotA")
    viewer, assembler, features, inference = (robot_b.session(wait=10, identity=name) for name in names)
    seen: list[tuple[str, bytes]] = []
    subscriber = viewer.declare_subscriber(
        "afford/@v1/**", lambda sample: seen.append((str(sample.key_expr), sample.payload.to_bytes()))
    )
    # keys no service of the test's robots consumes, so the controls change no running map
    writes = [
        (assembler, "map/pose"),
        (features, "status/features"),
        (inference, "affordance/test-only"),
    ]
    try:
        time.sleep(1.0)
        for session, key in writes:
            session.put(B.key(key), b"forged on robot B")
            session.put(A.key(key), b"own on robot A")
        assert eventually(
            lambda: sum(payload == b"own on robot A" for _, payload in seen) == 3, timeout=10
        ), seen
        time.sleep(1.0)
    finally:
        subscriber.undeclare()
        for session in (viewer, assembler, features, inference):
            session.close()
    assert [key for key, payload in seen if payload == b"forged on robot B"] == []
