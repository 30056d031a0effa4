"""What every service shares: the robot's key space, the zenoh session, status and errors, latest-output
queryables, a work loop fed from zenoh callbacks, its Rerun recording, and a clean stop on SIGINT/SIGTERM.

Zenoh calls the subscriber callbacks on its own threads; they only put samples in an inbox. One worker (the
main thread) takes them out and does the work, so a slow input never stalls the network, the recording is
written from one thread, and a bad input is answered on the error key while the service goes on.
"""

from __future__ import annotations

import bisect
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from affordcore import version
from affordwire import messages

from .settings import ServiceSettings
from .transport import (
    PREFIX,
    Keys,
    encoding_of,
    open_session,
    put,
    put_message,
    schema_of,
    stop_on_signals,
)


@dataclass(eq=False)  # one input is itself only: set-aside inputs are found by identity
class Inbound:
    key: str
    schema: str
    encoding: str
    payload: bytes
    arrived: float
    is_input: bool = True  # False: the service's own work (idle, stop), answered alike but not counted
    input_timestamp: object = None  # the message's own Timestamp once decoded: a refusal carries it back
    input_source: str = ""  # ... its own source (a Cloud's source, a scan's frame_id), and
    input_scans: int = 0  # ... the scans it covers (a Cloud's): so a waiter knows which refusal is its own
    checked: object = None  # what the inbox's check made of it on arrival (the decoded, validated message)
    taken: bool = False  # counted in Status.accepted while it is worked on; a refusal moves it to rejected
    passed_over: bool = False  # counted in Status.skipped: superseded, or passed over to keep up


# inputs an inbox keeps set aside for a newer one not yet found sound (beside the bound on those waiting)
SET_ASIDE = 4
# refusals each service keeps and answers a get on its error key with (a late waiter finds its own)
REFUSALS_KEPT = 32
# the timestamps of inputs received and not refused a service keeps, newest last: its Status.newest_input
STAMPS_KEPT = 256


def _own_work(what: str) -> Inbound:
    return Inbound(f"({what})", "", "", b"", time.time(), is_input=False)


class BoundedInbox:
    """What every inbox shares: inputs waiting for the worker (`_items`, a deque or a mapping), bounded in
    count (`limit`) and bytes (`max_bytes`), with the inputs passed over counted in `skipped`. Subclasses say
    how an input is queued (`offer`) and which one goes next (`take`)."""

    def __init__(self, items, limit: int, max_bytes: int):
        self.limit, self.max_bytes = limit, max_bytes
        self._items = items
        self._bytes = 0
        self._ready = threading.Condition()
        self.skipped = 0
        self.skipped_last: Inbound | None = None
        self.offered = 0  # every input offered, taken or refused
        # validates each input on arrival (on zenoh's thread), before it may supersede or delay anything: what
        # it returns is the item's `checked`; a ValueError refuses the input there and then
        self.check: Callable[[Inbound, object], object] | None = None  # (input, its message if it parsed)
        # inputs superseded by newer ones not yet found sound (newest last): one comes back when the input
        # that superseded it is refused, so a bad input never costs a good one its answer
        self._set_aside: deque[Inbound] = deque(maxlen=SET_ASIDE)

    def settled(self) -> int:
        """How many inputs offered are no longer waiting: taken, passed over, or refused."""
        with self._ready:
            return self.offered - len(self._items)

    def _too_big(self, size: int) -> str | None:
        """Why a payload of `size` bytes can never be taken, if it cannot."""
        if size > self.max_bytes:
            return (
                f"the payload is {size:,} bytes, above AFFORD_SERVICE__MAX_QUEUE_BYTES ({self.max_bytes:,})"
            )
        return None

    def _over_bytes(self, size: int, freed: int = 0) -> str | None:
        """Why `size` more bytes are refused (once the `freed` bytes of an input it replaces are gone), if
        they are."""
        if self._bytes - freed + size > self.max_bytes:
            return (
                f"{self._bytes:,} bytes are waiting; this one's {size:,} would pass "
                f"AFFORD_SERVICE__MAX_QUEUE_BYTES ({self.max_bytes:,}); it was not taken"
            )
        return None

    def _pass_over(self, item: Inbound) -> None:
        self.skipped += 1
        self.skipped_last = item
        item.passed_over = True

    def set_aside(self, item: Inbound) -> None:
        """Keep `item` (superseded, or worked on and given up for a newer input) until an input newer than it
        is answered: if that one is refused, `give_back` puts `item` back."""
        with self._ready:
            self._set_aside.append(item)

    def settle(self, answered: Inbound) -> None:
        """`answered` was worked on without a refusal: the inputs of its key set aside before it are no longer
        wanted (one it set aside itself, given up for a newer input, stays)."""
        with self._ready:
            kept = [i for i in self._set_aside if i.key != answered.key or i.arrived >= answered.arrived]
            self._set_aside = deque(kept, maxlen=SET_ASIDE)

    def give_back(self, refused: Inbound) -> Inbound | None:
        """After `refused` was refused: the newest input of its key set aside goes back to the worker, unless
        a newer one waits (which supersedes it anyway). Returns it, or None."""
        with self._ready:
            kept = [item for item in self._set_aside if item.key == refused.key and item is not refused]
            newest = max(kept, key=lambda item: item.arrived, default=None)
            return newest if newest is not None and self.recall(newest) else None

    def recall(self, item: Inbound) -> bool:
        """Put `item`, set aside, back in line unless an input of its key waits; whether it was."""
        with self._ready:
            if item not in self._set_aside or self.supersedes(item.key):
                return False
            self._set_aside.remove(item)
            if item.passed_over:  # it is worked on after all
                self.skipped -= 1
                item.passed_over = False
            self._put_back(item)
            self._bytes += len(item.payload)
            self._ready.notify()
            return True

    def _put_back(self, item: Inbound) -> None:
        raise NotImplementedError

    def drain(self) -> int:
        """Empty the inbox; returns how many inputs it held (those set aside were counted as skipped)."""
        with self._ready:
            count = len(self._items)
            self._items.clear()
            self._set_aside.clear()
            self._bytes = 0
            return count

    def forget(self) -> int:
        """`drain`, and count the inputs settled from here on only (a map after a reset covers none)."""
        with self._ready:
            count = self.drain()
            self.offered = 0
            return count

    def __len__(self) -> int:
        return len(self._items)


class Inbox(BoundedInbox):
    """Samples waiting for the worker, bounded in count and in bytes. `latest_only` keeps just the newest (a
    map superseded before it was worked on is not worth the work; it is counted in `skipped`); otherwise
    first in, first out, and when `max_lag` is set an input older than that is passed over (counted too) if
    a newer one waits that arrived within `max_gap` seconds of the last one taken: a sensor stream the worker
    cannot follow is thinned rather than left to build a lag, and the frames taken are never more than
    `max_gap` apart (registration bridges a short gap, not a long one)."""

    def __init__(
        self,
        latest_only: bool,
        limit: int,
        max_bytes: int,
        max_lag: float | None = None,
        max_gap: float = 0.0,
    ):
        super().__init__(deque(), limit, max_bytes)
        self.latest_only, self.max_lag, self.max_gap = latest_only, max_lag, max_gap
        self._last_taken: float | None = None  # arrival time of the last input taken
        self.on_queued: Callable[[], None] | None = None  # hears of each input queued (on zenoh's thread)

    def offer(self, item: Inbound) -> str | None:
        """None when taken, else why not (the caller answers it on the error key: nothing is dropped
        silently)."""
        size = len(item.payload)
        with self._ready:
            self.offered += 1
            if refusal := self._too_big(size):
                return refusal
            if self.latest_only:  # the one waiting is superseded: passed over, counted and set aside
                for waiting in self._items:
                    self._pass_over(waiting)
                    self._set_aside.append(waiting)
                self._items.clear()
                self._bytes = 0
            elif len(self._items) >= self.limit:
                return (
                    f"{len(self._items)} inputs are waiting (AFFORD_SERVICE__MAX_QUEUE); this one is refused"
                )
            elif refusal := self._over_bytes(size):
                return refusal
            self._items.append(item)
            self._bytes += size
            self._ready.notify()
        if self.on_queued is not None:
            self.on_queued()
        return None

    def take(self, timeout: float) -> Inbound | None:
        with self._ready:
            if not self._items and not self._ready.wait_for(lambda: self._items, timeout):
                return None
            item = self._pop()
            while self._passed_over(item):  # the stream's first input is always taken
                self._pass_over(item)
                item = self._pop()
            self._last_taken = item.arrived
            return item

    def _passed_over(self, item: Inbound) -> bool:
        """Late, and the next one waiting is still within `max_gap` of the last input taken."""
        late = self.max_lag is not None and time.time() - item.arrived > self.max_lag
        return (
            late
            and bool(self._items)
            and self._last_taken is not None
            and self._items[0].arrived - self._last_taken <= self.max_gap
        )

    def _pop(self) -> Inbound:
        item = self._items.popleft()
        self._bytes -= len(item.payload)
        return item

    def supersedes(self, key: str) -> bool:
        """Whether an input waiting here is newer than what a get on `key` brings (latest-only: any is)."""
        return bool(self._items)

    def _put_back(self, item: Inbound) -> None:
        self._items.appendleft(item)


def _inbound(sample) -> Inbound:
    return Inbound(
        str(sample.key_expr), schema_of(sample), str(sample.encoding), sample.payload.to_bytes(), time.time()
    )


def unused_path(path: Path) -> Path:
    """`path`, or when it exists `name-1.rrd`, `name-2.rrd`, ...: a restarted service never overwrites the
    recording of the run before it (the one that crashed is the one worth reading)."""
    candidate, number = path, 0
    while candidate.exists():
        number += 1
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
    return candidate


class Node:
    """One service process: `service` is its name (assembler, features, inference)."""

    def __init__(
        self,
        service: str,
        robot: str,
        endpoints: list[str],
        settings: ServiceSettings | None = None,
        rrd: Path | None = None,
        viewer: str | None = None,
        affordances: list[str] | None = None,
        listen: list[str] | None = None,
        models: list | None = None,
        keys=None,
    ):
        """`keys`: the key space when it is not one robot's (a sharded worker's, services/shard.py)."""
        from affordcore.mapping.recording import open_recording, recording_name

        self.service, self.keys = service, keys if keys is not None else Keys(robot)
        self.settings = settings or ServiceSettings()
        self.models = list(models or [])  # what a scoring service (inference) scores with
        self.mapper = None  # a scoring service's `ForkedRoomMapper`, when it was given one (registry)
        self.stop_event = threading.Event()
        stop_on_signals(self.stop_event)  # from the start: a SIGTERM while starting up is a clean stop too
        self.counts = {"accepted": 0, "rejected": 0, "published": 0, "skipped": 0, "dropped": 0}
        self.counts["refused_on_arrival"] = 0
        self.last_seconds = 0.0
        # nanoseconds, sorted: the stamps of inputs received and not refused (the last is Status.newest_input)
        self._stamps: list[int] = []
        # (error key, Error) of the latest refusals, answered on a get
        self._refusals: deque[tuple[str, bytes]] = deque(maxlen=REFUSALS_KEPT)
        self.no_output = ""  # why the inputs taken so far make no output (Status; the service sets it)
        self.on_reset: Callable[[], None] | None = None  # what the service forgets at an operator's reset
        self._reset: messages.Reset | None = None  # a reset asked for, carried out by the worker
        self.last_reset = None  # the Timestamp of the last reset carried out (Status.last_reset)
        self.latest: dict[str, tuple[bytes, object]] = {}  # key: (payload, encoding) answered on get
        self._declared: list = []
        self._lock = threading.Lock()
        recording_id = self.settings.service.recording_id or f"afford-{robot}"
        self.rrd = unused_path(Path(rrd or f"{service}.rrd"))
        self.recording = open_recording(
            self.rrd, affordances or [], recording_id, viewer, name=recording_name(robot)
        )
        service_settings = self.settings.service
        self.session = open_session(
            endpoints, service_settings.mode, listen, service_settings.zenoh_config, None, self.stop_event
        )
        self.state, self.detail = messages.Status.STARTING, "starting"
        self._declared.append(self.session.liveliness().declare_token(self.keys.status(service)))
        self.answer_refusals()
        if isinstance(self.keys, Keys):  # one robot's service (a sharded worker serves many: not reset)
            self._declared.append(self.session.declare_subscriber(self.keys.reset, self._on_reset))
        self._declared.append(
            self.session.declare_queryable(
                self.keys.status(service),
                lambda query: query.reply(
                    self.keys.status(service),
                    self._status().SerializeToString(),
                    encoding=encoding_of(messages.Status),
                ),
            )
        )

    def hold(self, entity):
        """Keep a zenoh entity a service declared itself until the node closes (undeclared in reverse order of
        declaration, before the session closes); returns it."""
        self._declared.append(entity)
        return entity

    # -- inputs ----------------------------------------------------------------------------------------------

    def inbox(self, latest_only: bool, skip_when_late: bool = False) -> Inbox:
        """An inbox bounded by the service settings; `skip_when_late`: pass over inputs older than
        AFFORD_SERVICE__MAX_LAG when newer ones wait."""
        service = self.settings.service
        max_lag = service.max_lag if skip_when_late else None
        return Inbox(latest_only, service.max_queue, service.max_queue_bytes, max_lag, service.max_gap)

    def subscribe(
        self, key: str, inbox: Inbox, schema: str | None = None, accept: Callable[[str], bool] | None = None
    ) -> None:
        """Samples on `key` into `inbox`; `schema` tags each as that schema whatever its encoding says (ROS 2
        publishers send CDR with no afford schema: services/ros.py names what the subscription is for);
        `accept(key)` False passes a sample over unread (another worker's share)."""

        def on_sample(sample) -> None:
            if accept is not None and not accept(str(sample.key_expr)):
                return
            item = _inbound(sample)
            if schema is not None:
                item.schema = schema
            self._offer(inbox, item)

        self._declared.append(self.session.declare_subscriber(key, on_sample))

    def fetch_latest(
        self, key: str, inbox: Inbox, timeout: float = 5.0, accept: Callable[[str], bool] | None = None
    ) -> int:
        """Ask for the latest input published on `key` (its publisher answers a get), so a service that
        (re)starts after it went out still works on it; returns how many replies were taken (`accept` as
        in `subscribe`)."""
        taken = 0
        for reply in self.session.get(key, timeout=timeout):
            if reply.ok is None or (accept is not None and not accept(str(reply.ok.key_expr))):
                continue
            if not inbox.supersedes(str(reply.ok.key_expr)):  # what the subscriber brought meanwhile is newer
                taken += self._offer(inbox, _inbound(reply.ok))
        return taken

    def _offer(self, inbox: Inbox, item: Inbound) -> bool:
        """On zenoh's thread: name the input (so a refusal says what it refused), check it (a bad input is
        refused here, before it can supersede or delay a good one), and queue it."""
        message = self._identify(item)
        refusal = None
        if inbox.check is not None:
            try:
                item.checked = inbox.check(item, message)
            except Exception as error:  # noqa: BLE001 - whatever a hostile input makes a check raise
                refusal = str(error) if isinstance(error, ValueError) else f"{type(error).__name__}: {error}"
        if refusal is not None:  # not offered: the inbox never counts it among the inputs it settled
            with self._lock:
                self.counts["refused_on_arrival"] += 1
        refusal = refusal or inbox.offer(item)
        if refusal is not None:
            self.reject(item, refusal)
        elif item.input_timestamp is not None:
            self._note_stamp(messages.nanoseconds(item.input_timestamp))
        return refusal is None

    def _identify(self, item: Inbound):
        """The message the sample's schema names, if it parses (else None), the item named after it: its
        timestamp (if valid), its source (a Cloud's `source`, a sensor's `frame_id`), the scans it covers."""
        cls = messages.MESSAGE_CLASSES.get(item.schema)
        if cls is None:
            return None
        try:
            message = messages.parse(cls, item.payload)
        except messages.MessageError:
            return None
        names = cls.DESCRIPTOR.fields_by_name
        if "timestamp" in names:
            try:  # a forged far-future time names nothing: it is refused when checked
                messages.checked_seconds(message.timestamp, self.settings.limits)
                item.input_timestamp = message.timestamp
            except messages.MessageError:
                pass
        item.input_source = message.source if "source" in names else getattr(message, "frame_id", "")
        if "scans_received" in names:
            item.input_scans = max(message.frames, message.scans_received)
        return message

    def _note_stamp(self, stamp: int) -> None:
        """Keep the timestamp of an input received (taken or waiting): a client that just published reads the
        newest from the status to know which answer is the newest (afford watch)."""
        with self._lock:
            bisect.insort(self._stamps, stamp)
            del self._stamps[:-STAMPS_KEPT]

    def decode(self, item: Inbound, *message_classes, parsed=None):
        """The message of the class the sample's schema names, among `message_classes`, or MessageError;
        `parsed`: the message already parsed from it (`_identify`), taken as it is."""
        names = {messages.schema_name(cls): cls for cls in message_classes}
        if item.schema not in names:
            raise messages.MessageError(
                f"expected encoding application/protobuf with schema {' or '.join(names)}, got "
                f"{item.encoding!r}"
            )
        cls = names[item.schema]
        message = parsed if isinstance(parsed, cls) else messages.parse(cls, item.payload)
        if "timestamp" in message.DESCRIPTOR.fields_by_name:
            item.input_timestamp = message.timestamp
        return message

    def reject(self, item: Inbound, reason: str, inbox: BoundedInbox | None = None) -> None:
        """Answer a bad input (or a failure of the service's own work) on error/<service>, naming what was
        refused; the service keeps running. Only inputs count in Status.rejected. A refused input is no
        longer the newest received, and what it superseded in `inbox` is given back to the worker."""
        error = messages.Error(
            service=self.service,
            key=item.key,
            encoding=item.encoding,
            payload_bytes=len(item.payload),
            reason=reason,
            input_source=item.input_source,
            input_scans=item.input_scans,
        )
        messages.stamp(error.timestamp)
        if item.input_timestamp is not None:
            error.input_timestamp.CopyFrom(item.input_timestamp)
            self._forget_stamp(messages.nanoseconds(item.input_timestamp))
        if item.is_input:
            with self._lock:  # in one step: a status never counts an input both taken and refused
                self.counts["rejected"] += 1
                if item.taken:
                    self.counts["accepted"] -= 1
                    item.taken = False
        error_key = self.keys.error_of(self.service, item.key)
        with self._lock:
            self._refusals.append((error_key, error.SerializeToString()))
        put_message(self.session, error_key, error)
        print(
            f"[{self.service}] {'rejected' if item.is_input else 'failed'} {item.key}: {reason}", flush=True
        )
        what = "rejected an input" if item.is_input else f"failed {item.key}"
        self.publish_status(messages.Status.READY, f"{what}: {reason}")
        back = inbox.give_back(item) if inbox is not None and item.is_input else None
        if back is not None:
            print(f"[{self.service}] took back the input it had superseded, from {back.key}", flush=True)

    def _forget_stamp(self, stamp: int) -> None:
        with self._lock:
            index = bisect.bisect_left(self._stamps, stamp)
            if index < len(self._stamps) and self._stamps[index] == stamp:
                del self._stamps[index]

    def answer_refusals(self) -> None:
        """A queryable on the service's error keys that replies with the refusals it still keeps (newest
        last), each on its own key: a client that starts waiting after its input was refused finds out."""
        from zenoh import KeyExpr

        def on_query(query) -> None:
            with self._lock:
                kept = list(self._refusals)
            for key, payload in kept:
                if KeyExpr(key).intersects(query.key_expr):
                    query.reply(key, payload, encoding=encoding_of(messages.Error))

        for key in self.keys.refusal_keys(self.service):
            self._declared.append(self.session.declare_queryable(key, on_query))

    # -- outputs ---------------------------------------------------------------------------------------------

    def answer_latest(self, key: str) -> None:
        """A queryable on `key` that replies with the latest output published there, if any."""

        def on_query(query) -> None:
            with self._lock:
                latest = self.latest.get(key)
            if latest is not None:
                query.reply(key, latest[0], encoding=latest[1])

        self._declared.append(self.session.declare_queryable(key, on_query))

    def publish(self, key: str, message, count: bool = True, keep: bool = True) -> None:
        """Put `message` on `key`; `keep`: as the latest a queryable of `answer_latest` answers with."""
        payload = message.SerializeToString()
        encoding = encoding_of(type(message))
        with self._lock:
            if keep:
                self.latest[key] = (payload, encoding)
            if count:
                self.counts["published"] += 1
        put(self.session, key, payload, encoding)

    def _status(self) -> messages.Status:
        """The service's status now (a get on its status key answers this, not the last one published)."""
        with self._lock:
            status = messages.Status(
                service=self.service,
                robot=self.keys.robot,
                state=self.state,
                detail=self.detail,
                last_seconds=self.last_seconds,
                version=version(),
                **self.counts,
            )
            if self._stamps:  # unset: none yet
                status.newest_input.FromNanoseconds(self._stamps[-1])
            if self.last_reset is not None:
                status.last_reset.CopyFrom(self.last_reset)
            status.no_output = self.no_output
        messages.stamp(status.timestamp)
        return status

    def publish_status(self, state: int, detail: str) -> None:
        with self._lock:
            self.state, self.detail = state, detail
        put_message(self.session, self.keys.status(self.service), self._status())

    # -- the work loop ---------------------------------------------------------------------------------------

    def run(
        self,
        inbox: Inbox,
        handle: Callable[[Inbound], None],
        idle: Callable[[], None] | None = None,
        on_stop: Callable[[], str] | None = None,
    ) -> None:
        """Take inputs until SIGINT/SIGTERM: `handle` each, `idle` when none came for a moment; an exception
        in either, whatever its type, is answered on the error key and the service goes on. At the stop,
        inputs still waiting are counted as dropped and `on_stop` saves what the service holds (its return
        says what); then everything closes, the recording last."""
        self.publish_status(messages.Status.READY, "waiting for input")
        print(
            f"[{self.service}] ready: robot {self.keys.robot}, keys {PREFIX}/{self.keys.robot}/...",
            flush=True,
        )
        last_status = time.monotonic()
        try:
            while not self.stop_event.is_set():
                if self._reset is not None:
                    self._carry_out_reset(inbox)
                item = inbox.take(timeout=0.2)
                self._note_skipped(inbox)
                if item is not None:
                    self._handle(item, handle, inbox)
                elif idle is not None:
                    self._guarded(_own_work("idle"), lambda _: idle())
                if time.monotonic() - last_status > self.settings.service.status_period:
                    self.publish_status(messages.Status.READY, f"{len(inbox)} inputs waiting")
                    last_status = time.monotonic()
        finally:
            with self._lock:
                self.counts["dropped"] += inbox.drain()
            if on_stop is not None:
                self._guarded(
                    _own_work("stop"),
                    lambda _: print(f"[{self.service}] {on_stop()}", flush=True),
                )
            self.close()

    def _on_reset(self, sample) -> None:
        """On zenoh's thread: an operator's Reset, checked; the worker carries it out between inputs."""
        item = _inbound(sample)
        try:
            reset = self.decode(item, messages.Reset)
            messages.checked_seconds(reset.timestamp, self.settings.limits)
        except messages.MessageError as error:
            self.reject(item, str(error))
            return
        with self._lock:
            self._reset = reset

    def _carry_out_reset(self, inbox: BoundedInbox) -> None:
        """Forget the robot's map and state: the inputs waiting, the outputs a get answers with, what the
        service holds (`on_reset`); the status says who reset it and when."""
        with self._lock:
            reset, self._reset = self._reset, None
        dropped = inbox.forget()
        with self._lock:
            self.counts["dropped"] += dropped
            self.latest.clear()
            self._stamps.clear()
            self.no_output = ""
            self.last_reset = reset.timestamp
        if self.on_reset is not None:
            self._guarded(_own_work("reset"), lambda _: self.on_reset())
        by = reset.operator or "an operator"
        print(f"[{self.service}] reset by {by} ({reset.reason or 'no reason given'})", flush=True)
        self.publish_status(
            messages.Status.READY,
            f"reset by {by}" + (f" ({reset.reason})" if reset.reason else "") + f"; {dropped} inputs dropped",
        )

    def _note_skipped(self, inbox: Inbox) -> None:
        with self._lock:
            newly = inbox.skipped - self.counts["skipped"]
            self.counts["skipped"] = inbox.skipped
        if newly > 0:  # an input given back after a refusal is no longer skipped
            last = inbox.skipped_last
            self.publish_status(
                messages.Status.BUSY,
                f"skipped {newly} inputs to keep up ({inbox.skipped} in all), the last on {last.key} that "
                f"waited {time.time() - last.arrived:.2f} s (AFFORD_SERVICE__MAX_LAG)",
            )

    def _handle(self, item: Inbound, handle: Callable[[Inbound], None], inbox: BoundedInbox) -> None:
        with self._lock:  # counted before its outputs go out, so a status read after them includes it
            if not item.taken:  # an input given back after it was worked on is counted once
                self.counts["accepted"] += 1
                item.taken = True
            self.state, self.detail = messages.Status.BUSY, f"working on an input from {item.key}"
        started = time.perf_counter()
        if self._guarded(item, handle, inbox):  # a refusal moved it from accepted to rejected (`reject`)
            self.last_seconds = time.perf_counter() - started
            inbox.settle(item)
        with self._lock:  # a handler that said nothing more leaves the service ready
            if self.state == messages.Status.BUSY:
                self.state, self.detail = messages.Status.READY, "waiting for input"

    def _guarded(
        self, item: Inbound, work: Callable[[Inbound], None], inbox: BoundedInbox | None = None
    ) -> bool:
        """Run `work`; any exception is answered on the error key (ours by name, anything else with its type:
        that one is a bug to report) and False returned. Only leaving the process gets through."""
        try:
            work(item)
        except (ValueError, MemoryError) as error:  # MessageError, CloudError, ModelError, limits, no floor
            self.reject(item, str(error) or type(error).__name__, inbox)
            return False
        except Exception as error:  # noqa: BLE001 - a service on a shared network must outlive its bugs
            traceback.print_exc()
            self.reject(item, f"internal error, {type(error).__name__}: {error}", inbox)
            return False
        return True

    def close(self) -> None:
        from affordcore.mapping.recording import close_recording

        try:
            self.publish_status(messages.Status.STOPPING, "shutting down")
        except Exception:  # the session may already be gone; closing the recording matters more
            pass
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:
                pass
        self.session.close()
        warning = close_recording(self.recording)
        if warning:
            print(f"[{self.service}] {warning}", flush=True)
        counts = self.counts
        print(
            f"[{self.service}] stopped: {counts['accepted']} inputs taken, {counts['rejected']} rejected, "
            f"{counts['skipped']} skipped to keep up, {counts['dropped']} dropped at the stop (waiting), "
            f"{counts['published']} outputs published; recording {self.rrd}",
            flush=True,
        )
