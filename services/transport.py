"""The transport every service and client shares: the robot's key space, the zenoh session, encodings, and the
one way anything is published (congestion control BLOCK)."""

from __future__ import annotations

import json
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from affordwire import messages

PREFIX = "afford/@v1"
# the sharded workers' own keys (membership tokens, status): `@workers` is a verbatim chunk, so no robot key
# expression (`afford/@v1/*/...`, `afford/@v1/**`) reaches them, and no robot can be named so (no `@`)
WORKERS = f"{PREFIX}/@workers"
_NOT_IN_A_NAME = "/*$?#@ "


@dataclass(frozen=True)
class Keys:
    """The key space of one robot (DESIGN.md, "Processes and key space")."""

    robot: str

    def __post_init__(self) -> None:
        if not self.robot or any(c in self.robot for c in _NOT_IN_A_NAME):
            raise ValueError(
                f"robot name {self.robot!r} must be one non-empty key chunk (no / * $ ? # @ or spaces)"
            )

    def key(self, *chunks: str) -> str:
        return "/".join((PREFIX, self.robot, *chunks))

    scans = property(lambda self: self.key("scan", "**"))
    cloud = property(lambda self: self.key("map", "cloud"))
    pose = property(lambda self: self.key("map", "pose"))
    fields = property(lambda self: self.key("fields"))
    next_views = property(lambda self: self.key("next-views"))
    reset = property(lambda self: self.key("control", "reset"))  # an operator's (docs/security.md)

    def scan(self, sensor: str) -> str:
        return self.key("scan", sensor)

    def affordance(self, name: str) -> str:
        return self.key("affordance", name)

    def status(self, service: str) -> str:
        return self.key("status", service)

    def error(self, service: str) -> str:
        return self.key("error", service)

    def error_of(self, service: str, input_key: str) -> str:
        """Where `service` answers a refusal of an input that came on `input_key`: this robot's error key (a
        worker serving several robots answers on the input's robot's: services/shard.py)."""
        return self.error(service)

    def refusal_keys(self, service: str) -> list[str]:
        """Every key `service` answers refusals on (its queryable replies there with the ones it keeps)."""
        return [self.error(service)]


def robot_of(key: str) -> str | None:
    """The robot a concrete key of the afford key space belongs to (`afford/@v1/<robot>/...`), or None for any
    other key (the workers' own, a service's own work)."""
    chunks = key.split("/")
    if len(chunks) < 4 or "/".join(chunks[:2]) != PREFIX:
        return None
    try:
        return Keys(chunks[2]).robot
    except ValueError:
        return None


def robot_pattern(pattern: str) -> str:
    """A selection of robots as one key chunk: a robot name, `*` (every robot) or a name with `$*` wildcards
    (`lab-$*`: every robot whose name starts with lab-). Never more than one chunk (no `**`, no `/`), and
    never a verbatim chunk (`@...`): a selection reaches robots' keys only."""
    import zenoh

    if pattern == "*":
        return pattern
    if not pattern or any(c in pattern.replace("$*", "") for c in _NOT_IN_A_NAME):
        raise ValueError(
            f"robot selection {pattern!r} must be a robot name, * or a name with $* wildcards (lab-$*)"
        )
    try:
        zenoh.KeyExpr(f"{PREFIX}/{pattern}/fields")
    except zenoh.ZError as error:
        raise ValueError(f"robot selection {pattern!r} is not a key chunk: {error}") from None
    return pattern


def zenoh_config(
    endpoints: list[str], mode: str = "client", listen: list[str] | None = None, base: Path | None = None
):
    """A zenoh config: `base` (a JSON5 file with TLS, access control, ...) when given, with explicit endpoints
    and mode on top, and no multicast scouting (robots share networks; tests share a machine): a process
    talks to the router it is told about and to nothing it happens to hear."""
    import zenoh

    if base is not None:
        if not Path(base).is_file():
            raise ValueError(f"zenoh config {base} does not exist")
        config = zenoh.Config.from_file(str(base))
        _anchor_tls_files(config, Path(base).parent)
    else:
        config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    if endpoints:
        config.insert_json5("connect/endpoints", json.dumps(list(endpoints)))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("scouting/multicast/enabled", "false")
    if mode != "router":  # keep trying while the router is not up yet (services may start first)
        config.insert_json5("connect/exit_on_failure", "false")
    return config


TLS_FILES = (
    "root_ca_certificate",
    "listen_certificate",
    "listen_private_key",
    "connect_certificate",
    "connect_private_key",
)


def _anchor_tls_files(config, folder: Path) -> None:
    """Relative certificate and key paths in a config file name files beside it (as `afford certs` writes
    them, so a site folder works wherever it is copied); zenoh itself would read them from the working
    directory."""
    import zenoh

    for name in TLS_FILES:
        key = f"transport/link/tls/{name}"
        try:
            value = json.loads(config.get_json(key))
        except (zenoh.ZError, ValueError):
            continue
        if isinstance(value, str) and value and not Path(value).is_absolute():
            config.insert_json5(key, json.dumps(str((folder / value).absolute())))


def open_session(
    endpoints: list[str],
    mode: str = "client",
    listen: list[str] | None = None,
    base: Path | None = None,
    wait: float | None = 30.0,
    stop: threading.Event | None = None,
):
    """A zenoh session. A client cannot open one before its router is up, so it retries for `wait` seconds
    (None: until `stop` is set; services start in any order on a robot), then raises the last error."""
    import zenoh

    zenoh.init_log_from_env_or("error")
    config = zenoh_config(endpoints, mode, listen, base)
    deadline = None if wait is None else time.monotonic() + wait
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            if mode != "client" or (stop is not None and stop.is_set()):
                raise
            if deadline is not None and time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def encoding_of(message_class):
    """application/protobuf with the message's full name as schema (what every publication carries)."""
    import zenoh

    return zenoh.Encoding.APPLICATION_PROTOBUF.with_schema(messages.schema_name(message_class))


def _block():
    """Congestion control BLOCK for every publication: zenoh's default (DROP) loses multi-megabyte samples
    under load (DESIGN.md)."""
    import zenoh

    return zenoh.CongestionControl.BLOCK


def put(session, key: str, payload: bytes, encoding=None) -> None:
    """Publish bytes with their encoding, zenoh's default when None (congestion control BLOCK)."""
    session.put(key, payload, encoding=encoding, congestion_control=_block())


def put_message(session, key: str, message) -> None:
    """Publish a protobuf message with its schema (congestion control BLOCK)."""
    put(session, key, message.SerializeToString(), encoding_of(type(message)))


def declare_publisher(session, key: str, message_class):
    """A publisher of `message_class` on `key` (congestion control BLOCK), for a stream of messages."""
    return session.declare_publisher(key, encoding=encoding_of(message_class), congestion_control=_block())


def schema_of(sample) -> str:
    """The schema named in a sample's encoding ('' when it carries none)."""
    text = str(sample.encoding)
    return text.split(";", 1)[1] if text.startswith("application/protobuf;") else ""


def stop_on_signals(stop: threading.Event) -> None:
    """SIGINT and SIGTERM set `stop` (only the main thread may install handlers; a service run in a thread,
    as in the tests, is stopped through its event)."""
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
