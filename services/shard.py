"""Sharded workers: several processes of one service share the inputs of many robots, with no state shared
beyond what is on the wire (docs/deploy.md).

Each worker of a group holds a liveliness token `afford/@v1/@workers/<group>/<worker>` and watches the
others'; a unit of work (a robot and one of its affordances, or a whole robot) belongs to the live worker
with the highest rendezvous weight (highest-random-weight hashing), so every worker that sees the same tokens
agrees on the owner without talking, a worker that joins takes only its own share from the others, and the
share of a worker that leaves spreads over the rest. The group's name is derived from what its workers do
(the robots they select, the unit, the models): workers configured alike share the work; workers configured
differently are separate groups, which may duplicate work but never leave an input to nobody.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from .node import BoundedInbox, Inbound
from .transport import PREFIX, WORKERS, Keys, robot_of, robot_pattern

UNITS = ("affordance", "robot")  # what one owner takes: each (robot, affordance), or all of a robot's


@dataclass(frozen=True)
class Selection:
    """The robots a worker serves: robot names and one-chunk key patterns (`*`, `lab-$*`)."""

    patterns: tuple[str, ...]

    def __post_init__(self) -> None:
        if not self.patterns:
            raise ValueError("a worker serves at least one robot name or pattern (* for every robot)")
        for pattern in self.patterns:
            robot_pattern(pattern)

    def keys(self, *chunks: str) -> list[str]:
        """One key expression per pattern, e.g. keys("fields") -> ["afford/@v1/*/fields"]."""
        return ["/".join((PREFIX, pattern, *chunks)) for pattern in self.patterns]

    def includes(self, robot: str) -> bool:
        import zenoh

        key = zenoh.KeyExpr(f"{PREFIX}/{Keys(robot).robot}")
        return any(zenoh.KeyExpr(f"{PREFIX}/{pattern}").includes(key) for pattern in self.patterns)

    def __str__(self) -> str:
        return ",".join(self.patterns)


def weight(worker: str, unit: str) -> int:
    """The rendezvous weight of `worker` for `unit`: a 64-bit hash of both, the same on every host."""
    digest = hashlib.blake2b(f"{worker}\n{unit}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def owner(workers: Iterable[str], unit: str) -> str:
    """The worker that owns `unit` among `workers`: the highest weight (ties, never seen in practice, by
    name)."""
    return max(workers, key=lambda worker: (weight(worker, unit), worker))


def check_worker_id(worker: str) -> str:
    if not worker or not all(c.isalnum() or c in "-_." for c in worker):
        raise ValueError(f"worker id {worker!r}: use letters, digits, '-', '_' or '.'")
    return worker


def default_worker_id() -> str:
    """<host>-<pid>: unique on a site as long as host names are."""
    host = "".join(c if c.isalnum() or c in "-_." else "-" for c in socket.gethostname()) or "host"
    return f"{host}-{os.getpid()}"


def group_of(service: str, selection: Selection, unit: str, model_ids: Iterable[str]) -> str:
    """`<service>-<digest>`: the digest of what the workers do, so only workers configured alike share."""
    what = json.dumps([service, sorted(selection.patterns), unit, sorted(model_ids)])
    return f"{service}-{hashlib.blake2b(what.encode(), digest_size=4).hexdigest()}"


@dataclass(frozen=True)
class WorkerKeys:
    """The key space of one worker of a sharded service: the robots it selects, its group and its id.

    * `afford/@v1/@workers/<group>/<worker>`: its liveliness token, the group's membership;
    * `.../<worker>/status` and `.../<worker>/error`: its Status (service `<service>-<worker>`) and the errors
      of its own work;
    * `afford/@v1/<robot>/error/<service>-<worker>`: its refusals of that robot's inputs;
    * its outputs on the robots' usual keys (`afford/@v1/<robot>/affordance/<name>`).
    """

    selection: Selection
    group: str
    worker: str
    unit: str = "affordance"

    def __post_init__(self) -> None:
        check_worker_id(self.worker)
        check_worker_id(self.group)
        if self.unit not in UNITS:
            raise ValueError(f"shard unit {self.unit!r}: choose one of {', '.join(UNITS)}")

    robot = property(lambda self: str(self.selection))  # what Status.robot says
    member = property(lambda self: f"{WORKERS}/{self.group}/{self.worker}")
    members = property(lambda self: f"{WORKERS}/{self.group}/*")

    def status(self, service: str) -> str:
        return f"{self.member}/status"

    def error(self, service: str) -> str:
        return f"{self.member}/error"

    def error_of(self, service: str, input_key: str) -> str:
        robot = robot_of(input_key)
        return Keys(robot).error(service) if robot else self.error(service)

    def refusal_keys(self, service: str) -> list[str]:
        return [self.error(service), f"{PREFIX}/*/error/{service}"]

    def unit_of(self, robot: str, affordance: str) -> str:
        return f"{robot}/{affordance}" if self.unit == "affordance" else robot


class Membership:
    """The live workers of a group as this one sees them (itself always among them), from their liveliness
    tokens; `on_change(before, after)` hears of every change, on the thread that noticed it."""

    def __init__(self, me: str, on_change: Callable[[frozenset, frozenset], None]):
        self.me, self.on_change = me, on_change
        self._workers: frozenset[str] = frozenset({me})
        self._lock = threading.Lock()

    def view(self) -> frozenset[str]:
        with self._lock:
            return self._workers

    def owns(self, unit: str) -> bool:
        return owner(self.view(), unit) == self.me

    def on_sample(self, sample) -> None:
        """A liveliness sample on the group's key: a worker joined (PUT) or left (DELETE)."""
        import zenoh

        worker = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            before = self._workers
            if sample.kind == zenoh.SampleKind.PUT:
                self._workers = before | {worker}
            elif worker != self.me:
                self._workers = before - {worker}
            after = self._workers
        if after != before:
            self.on_change(before, after)

    def reconcile(self, workers: Iterable[str]) -> None:
        """Set the view to the tokens a liveliness get lists now (heals an event missed or out of order). An
        answer without this worker's own token is incomplete (the get timed out on a busy link): it may add
        workers, never remove one."""
        workers = frozenset(workers)
        with self._lock:
            before = self._workers
            after = workers | {self.me} if self.me in workers else before | workers
            self._workers = after
        if after != before:
            self.on_change(before, after)


class KeyedInbox(BoundedInbox):
    """The newest input per key, the key that waits longest first: a worker of many robots keeps each
    robot's latest fields (a single latest-only inbox would let one robot's input supersede another's).
    Bounded in keys and bytes like `Inbox`; the same interface for `Node.run`."""

    def __init__(self, limit: int, max_bytes: int):
        super().__init__(OrderedDict(), limit, max_bytes)

    def offer(self, item: Inbound) -> str | None:
        size = len(item.payload)
        with self._ready:
            self.offered += 1
            if refusal := self._too_big(size):
                return refusal
            old = self._items.get(item.key)
            if old is None and len(self._items) >= self.limit:
                return f"inputs of {len(self._items)} keys are waiting (AFFORD_SERVICE__MAX_QUEUE)"
            freed = len(old.payload) if old is not None else 0
            if refusal := self._over_bytes(size, freed):
                return refusal
            if old is not None:  # superseded: passed over, counted and set aside; the key keeps its place
                self._pass_over(old)
                self._set_aside.append(old)
            self._items[item.key] = item
            self._bytes += size - freed
            self._ready.notify()
        return None

    def take(self, timeout: float) -> Inbound | None:
        with self._ready:
            if not self._items and not self._ready.wait_for(lambda: self._items, timeout):
                return None
            _, item = self._items.popitem(last=False)
            self._bytes -= len(item.payload)
            return item

    def supersedes(self, key: str) -> bool:
        with self._ready:
            return key in self._items

    def _put_back(self, item: Inbound) -> None:
        self._items[item.key] = item
        self._items.move_to_end(item.key, last=False)  # it has waited longest


class LatestOutputs:
    """The newest output seen on the wire per key (whoever published it), with the stamp of the input it
    answers: what a new owner compares an input with, and answers a late `get` with."""

    def __init__(self):
        self._latest: dict[str, tuple[int, bytes, object]] = {}
        self._lock = threading.Lock()

    def take(self, key: str, stamp: int, payload: bytes, encoding) -> None:
        """Keep it unless an output of a newer input is kept already."""
        with self._lock:
            if key not in self._latest or stamp >= self._latest[key][0]:
                self._latest[key] = (stamp, payload, encoding)

    def stamp(self, key: str) -> int:
        """The input stamp of the newest output on `key`, -1 when none was seen."""
        with self._lock:
            return self._latest[key][0] if key in self._latest else -1

    def items(self) -> list[tuple[str, tuple[int, bytes, object]]]:
        with self._lock:
            return list(self._latest.items())

    def nbytes(self) -> int:
        with self._lock:
            return sum(len(payload) for _, payload, _ in self._latest.values())
