"""Only trusted clients get in: a secured site from `afford certs` (mutual TLS through the router, access
control by certificate common name), with the three services running as processes on loopback.

* TLS works: the services start, see each other and answer through the router;
* plain TCP, a client without a certificate, and a certificate from another CA are refused;
* a client with the site's certificate but no write rights (a viewer) cannot put map/cloud, fields,
  affordance/* or scans, nor answer a query for a map; the owners' and sensors' writes go through;
* no service listens on any port, so nothing can link to a service past the router.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest
from conftest import eventually

from services.launch import Stack
from services.security import Site, client_config, write_site
from services.transport import Keys

pytestmark = pytest.mark.slow
ROBOT = "robot1"
KEYS = Keys(ROBOT)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    folder = tmp_path_factory.mktemp("site")
    write_site(Site(sensors=["robot"], mappers=["mapper"], viewers=["viewer", "intruder"]), folder)
    return folder


@pytest.fixture(scope="module")
def stack(site, tmp_path_factory):
    stack = Stack(tmp_path_factory.mktemp("secured"), robot=ROBOT, site=site).start()
    yield stack
    codes = stack.stop()
    assert all(code == 0 for code in codes.values()), (codes, stack.logs())


def _open(config: dict, stack: Stack, tmp_path, name: str):
    """zenoh.open of a config written to a file, trying once: the session, or the error it raised."""
    import zenoh

    path = tmp_path / f"{name}.json5"
    path.write_text(json.dumps(config))
    config = zenoh.Config.from_file(str(path))
    config.insert_json5("connect/endpoints", json.dumps([stack.endpoint]))
    config.insert_json5("connect/timeout_ms", "3000")
    config.insert_json5("connect/exit_on_failure", "true")
    try:
        return zenoh.open(config)
    except zenoh.ZError as error:
        return error


def test_afford_certs_keeps_the_site_ca_and_grants_a_new_sensor(tmp_path):
    afford = [sys.executable, "-m", "affordcli", "certs", str(tmp_path)]
    first = subprocess.run(afford, capture_output=True, text=True, timeout=60)
    assert first.returncode == 0, first.stderr
    ca = (tmp_path / "ca.pem").read_bytes()
    again = subprocess.run(
        [*afford, "--sensor", "robot", "--sensor", "lidar-2"], capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "ca.pem").read_bytes() == ca  # certificates already handed out stay valid
    router = json.loads((tmp_path / "router.json5").read_text())
    subjects = {s["id"]: s for s in router["access_control"]["subjects"]}
    assert subjects["lidar-2"]["cert_common_names"] == ["lidar-2"]
    assert oct((tmp_path / "lidar-2.key").stat().st_mode & 0o777) == "0o600"
    bad = subprocess.run([*afford, "--viewer", "router"], capture_output=True, text=True)
    assert bad.returncode == 2 and "router" in bad.stderr


def test_a_secured_site_starts_and_answers_through_the_router(stack):
    session = stack.session(wait=10, identity="viewer")
    try:
        replies = [r for r in session.get(KEYS.key("status", "*"), timeout=5.0) if r.ok is not None]
    finally:
        session.close()
    assert {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies} == {"assembler", "features", "inference"}


def test_plain_tcp_no_certificate_and_a_foreign_ca_are_refused(stack, site, tmp_path):
    import zenoh

    base = client_config(Site(), site.absolute(), "assembler")
    plain = {**base, "transport": {}}  # no TLS at all
    plain_stack = Stack(tmp_path, site=None)
    plain_stack.endpoint = stack.endpoint.replace("tls/", "tcp/")
    no_cert = json.loads(json.dumps(base))
    tls = no_cert["transport"]["link"]["tls"]
    for key in ("connect_certificate", "connect_private_key"):
        del tls[key]
    tls["enable_mtls"] = False
    foreign = tmp_path / "foreign"
    write_site(Site(sensors=[], viewers=[]), foreign)  # another CA, same identity names
    forged = json.loads(json.dumps(base))
    forged["transport"]["link"]["tls"] |= {
        "connect_certificate": str(foreign / "assembler.pem"),
        "connect_private_key": str(foreign / "assembler.key"),
    }
    for name, config, target in [
        ("plain", plain, plain_stack),
        ("no-cert", no_cert, stack),
        ("forged", forged, stack),
    ]:
        session = _open(config, target, tmp_path, name)
        if not isinstance(session, zenoh.ZError):
            session.close()
        assert isinstance(session, zenoh.ZError), f"{name}: a session opened"
    # the same machinery with the real certificate does connect (the refusals are not a broken set-up)
    session = _open(base, stack, tmp_path, "good")
    assert not isinstance(session, zenoh.ZError), session
    session.close()


def test_only_owners_write_their_keys_and_a_viewer_writes_nothing(stack):
    viewer, intruder, robot, assembler, inference = (
        stack.session(wait=10, identity=name)
        for name in ("viewer", "intruder", "robot", "assembler", "inference")
    )
    seen: list[tuple[str, bytes]] = []
    subscriber = viewer.declare_subscriber(
        f"afford/@v1/{ROBOT}/**", lambda s: seen.append((str(s.key_expr), s.payload.to_bytes()))
    )
    fake_map = intruder.declare_queryable(
        KEYS.affordance("sitting-relaxing"),
        lambda query: query.reply(KEYS.affordance("sitting-relaxing"), b"forged map"),
    )
    # the positive control: the inference identity, which owns affordance/*, may answer for a map
    owned_map = inference.declare_queryable(
        KEYS.affordance("control"), lambda query: query.reply(KEYS.affordance("control"), b"owned map")
    )
    try:
        time.sleep(1.0)  # declarations reach the router
        forged = [
            KEYS.cloud,
            KEYS.pose,
            KEYS.fields,
            KEYS.affordance("sitting-relaxing"),
            KEYS.scan("camera"),
        ]
        forged += [KEYS.status("inference"), KEYS.error("features")]
        for key in forged:
            intruder.put(key, b"forged")
        robot.put(KEYS.cloud, b"forged")  # a sensor may send scans, not a map
        robot.put(KEYS.scan("lab-test"), b"sensor bytes")
        assembler.put(KEYS.affordance("sitting-working"), b"forged")  # a service writes only its own keys
        assert eventually(lambda: (KEYS.scan("lab-test"), b"sensor bytes") in seen, timeout=10)
        time.sleep(1.0)  # anything wrongly let through would have arrived by now
        replies = list(viewer.get(KEYS.affordance("*"), timeout=3.0))
    finally:
        fake_map.undeclare()
        owned_map.undeclare()
        subscriber.undeclare()
        for session in (viewer, intruder, robot, assembler, inference):
            session.close()
    assert [key for key, payload in seen if payload == b"forged"] == []
    answers = [r.ok.payload.to_bytes() for r in replies if r.ok is not None]
    assert b"owned map" in answers and b"forged map" not in answers, answers
    # the sensor's bytes reached the assembler, which refused them on its error key: the one way in works
    assert any(key == KEYS.error("assembler") for key, _ in seen)


def test_no_service_listens_so_nothing_bypasses_the_router(stack):
    for name in ("assembler", "features", "inference"):
        listening = [
            c.laddr
            for c in psutil.Process(stack.processes[name].pid).net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN or (c.type == 2 and not c.raddr)  # 2: UDP, bound without a peer
        ]
        assert listening == [], f"{name} listens on {listening}"


def test_a_mapper_publishes_a_room_and_a_viewer_gets_its_maps(stack, site, tmp_path):
    """The README's secured walk-through: every command with its identity's --zenoh-config."""
    from affordcore.example import example_room
    from affordcore.geometry.scene import save_cloud

    room = tmp_path / "example.ply"
    save_cloud(room, example_room())
    afford = [sys.executable, "-m", "affordcli"]
    endpoint = ["--connect", stack.endpoint, "--robot", ROBOT]
    watch = subprocess.Popen(
        [*afford, "watch", *endpoint, "--zenoh-config", str(site / "viewer.json5"), "--out", str(tmp_path)]
        + ["--timeout", "240", "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(2.0)
    published = subprocess.run(
        [*afford, "publish", str(room), "--as-map", *endpoint]
        + ["--zenoh-config", str(site / "mapper.json5")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert published.returncode == 0, published.stderr
    out, err = watch.communicate(timeout=300)
    assert watch.returncode == 0, (out, err, stack.logs())
    # the maps the viewer got are the room's: what `afford map` makes of the same file, without the site
    from test_end_to_end import place_rows

    alone = subprocess.run(
        [*afford, "map", str(room), "--out", str(tmp_path / "alone"), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert alone.returncode == 0, alone.stderr
    for name in ("sitting-relaxing", "sitting-working", "standing-working"):
        got = json.loads((tmp_path / f"{name}.json").read_text())
        want = json.loads((tmp_path / "alone" / f"{name}.json").read_text())
        assert got["affordance"] == name
        np.testing.assert_allclose(place_rows(got), place_rows(want), atol=1e-3, err_msg=name)
        assert len(got["positives"]) == len(want["positives"]), name


def _kept(stack, site) -> dict[str, int]:
    """How many replies a viewer's get has on the robot's map keys (the latest outputs the services keep)."""
    viewer = stack.session(identity="viewer")
    try:
        keys = {"cloud": KEYS.cloud, "fields": KEYS.fields, "maps": KEYS.affordance("*")}
        return {
            name: sum(r.ok is not None for r in viewer.get(key, timeout=3.0)) for name, key in keys.items()
        }
    finally:
        viewer.close()


def test_only_an_operator_resets_a_robot_and_it_maps_afresh_after(stack, site, tmp_path):
    """Run after the mapper's room is mapped: a sensor's reset is denied by the router (the maps stay); an
    operator's clears every service's map and state, and the next room is mapped as usual."""
    from affordcore.example import example_room
    from affordcore.geometry.scene import save_cloud

    afford = [sys.executable, "-m", "affordcli"]
    endpoint = ["--connect", stack.endpoint, "--robot", ROBOT]

    def reset(identity: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [
                *afford,
                "reset",
                *endpoint,
                "--zenoh-config",
                str(site / f"{identity}.json5"),
                "--timeout",
                "10",
            ]
            + ["--reason", f"test by {identity}"],
            capture_output=True,
            text=True,
            timeout=60,
        )

    before = _kept(stack, site)
    assert before == {"cloud": 0, "fields": 1, "maps": 3}, before  # a mapper's room: no assembler map
    denied = reset("robot")
    assert denied.returncode != 0, denied.stdout
    assert _kept(stack, site) == before, "a sensor cannot reset the robot"
    done = reset("operator")
    assert done.returncode == 0, done.stdout + done.stderr + stack.logs()
    assert "assembler, features, inference start afresh" in done.stdout
    assert _kept(stack, site) == {"cloud": 0, "fields": 0, "maps": 0}
    assert "reset by operator (test by operator)" in (stack.folder / "inference.log").read_text()

    room = tmp_path / "example.ply"
    save_cloud(room, example_room())
    watch = subprocess.Popen(
        [*afford, "watch", *endpoint, "--zenoh-config", str(site / "viewer.json5"), "--timeout", "240", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(2.0)
    published = subprocess.run(
        [*afford, "publish", str(room), "--as-map", *endpoint, "--zenoh-config", str(site / "mapper.json5")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert published.returncode == 0, published.stderr
    out, err = watch.communicate(timeout=300)
    assert watch.returncode == 0, (out, err)
    assert _kept(stack, site) == before
