"""What every service shares: the robot's key space, the zenoh session, status and errors, latest-output
queryables, a work loop fed from zenoh callbacks, its Rerun recording, and a clean stop on SIGINT/SIGTERM.

Zenoh calls the subscriber callbacks on its own threads; they only put samples in an inbox. One worker (the
main thread) takes them out and does the work, so a slow input never stalls the network, the recording is
written from one thread, and a bad input is answered on the error key while the service goes on.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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
    version,
)


@dataclass
class Inbound:
    key: str
    schema: str
    encoding: str
    payload: bytes
    arrived: float


class Inbox:
    """Samples waiting for the worker. `latest_only` keeps just the newest (a map superseded before it was
    worked on is not worth the work); otherwise first in, first out, up to `limit`."""

    def __init__(self, latest_only: bool, limit: int):
        self.latest_only = latest_only
        self._queue: queue.Queue = queue.Queue(maxsize=0 if latest_only else limit)
        self._lock = threading.Lock()

    def offer(self, item: Inbound) -> bool:
        """False when the inbox is full (the caller reports it; nothing is dropped silently)."""
        with self._lock:
            if self.latest_only:
                while not self._queue.empty():
                    self._queue.get_nowait()
            try:
                self._queue.put_nowait(item)
            except queue.Full:
                return False
        return True

    def take(self, timeout: float) -> Inbound | None:
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def __len__(self) -> int:
        return self._queue.qsize()


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
    ):
        from affordcore.recording import open_recording

        self.service, self.keys = service, Keys(robot)
        self.settings = settings or ServiceSettings()
        self.models = list(models or [])  # what a scoring service (inference) scores with
        self.stop_event = threading.Event()
        self.counts = {"accepted": 0, "rejected": 0, "published": 0}
        self.last_seconds = 0.0
        self.latest: dict[str, tuple[bytes, object]] = {}  # key: (payload, encoding) answered on get
        self._declared: list = []
        self._lock = threading.Lock()
        recording_id = self.settings.service.recording_id or f"afford-{robot}"
        self.recording = open_recording(
            rrd or Path(f"{service}.rrd"), affordances or [], recording_id, viewer
        )
        self.session = open_session(endpoints, self.settings.service.mode, listen)
        self.state, self.detail = messages.Status.STARTING, "starting"
        self._declared.append(self.session.liveliness().declare_token(self.keys.status(service)))
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

    # -- inputs ----------------------------------------------------------------------------------------------

    def subscribe(self, key: str, inbox: Inbox) -> None:
        def on_sample(sample) -> None:
            item = Inbound(
                str(sample.key_expr),
                schema_of(sample),
                str(sample.encoding),
                sample.payload.to_bytes(),
                time.time(),
            )
            if not inbox.offer(item):
                self.reject(
                    item,
                    f"{self.service} is {len(inbox)} inputs behind (AFFORD_SERVICE__MAX_QUEUE); this one "
                    "was not taken",
                )

        self._declared.append(self.session.declare_subscriber(key, on_sample))

    def decode(self, item: Inbound, *message_classes):
        """The message of the class the sample's schema names, among `message_classes`, or MessageError."""
        names = {messages.schema_name(cls): cls for cls in message_classes}
        if item.schema not in names:
            raise messages.MessageError(
                f"expected encoding application/protobuf with schema {' or '.join(names)}, got "
                f"{item.encoding!r}"
            )
        return messages.parse(names[item.schema], item.payload)

    def reject(self, item: Inbound, reason: str) -> None:
        """Answer a bad input on error/<service>; the service keeps running."""
        error = messages.Error(
            service=self.service,
            key=item.key,
            encoding=item.encoding,
            payload_bytes=len(item.payload),
            reason=reason,
        )
        messages.stamp(error.timestamp)
        with self._lock:
            self.counts["rejected"] += 1
        put_message(self.session, self.keys.error(self.service), error)
        print(f"[{self.service}] rejected {item.key}: {reason}", flush=True)
        self.publish_status(messages.Status.READY, f"rejected an input: {reason}")

    # -- outputs ---------------------------------------------------------------------------------------------

    def answer_latest(self, key: str) -> None:
        """A queryable on `key` that replies with the latest output published there, if any."""

        def on_query(query) -> None:
            with self._lock:
                latest = self.latest.get(key)
            if latest is not None:
                query.reply(key, latest[0], encoding=latest[1])

        self._declared.append(self.session.declare_queryable(key, on_query))

    def publish(self, key: str, message, count: bool = True) -> None:
        payload = message.SerializeToString()
        encoding = encoding_of(type(message))
        with self._lock:
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
        messages.stamp(status.timestamp)
        return status

    def publish_status(self, state: int, detail: str) -> None:
        with self._lock:
            self.state, self.detail = state, detail
        put_message(self.session, self.keys.status(self.service), self._status())

    # -- the work loop ---------------------------------------------------------------------------------------

    def run(
        self, inbox: Inbox, handle: Callable[[Inbound], None], idle: Callable[[], None] | None = None
    ) -> None:
        """Take inputs until SIGINT/SIGTERM: `handle` each (a ValueError rejects it), `idle` when none came
        for a moment. Then close everything, the recording last."""
        stop_on_signals(self.stop_event)
        self.publish_status(messages.Status.READY, "waiting for input")
        print(
            f"[{self.service}] ready: robot {self.keys.robot}, keys {PREFIX}/{self.keys.robot}/...",
            flush=True,
        )
        last_status = time.monotonic()
        try:
            while not self.stop_event.is_set():
                item = inbox.take(timeout=0.2)
                if item is not None:
                    self._handle(item, handle)
                elif idle is not None:
                    idle()
                if time.monotonic() - last_status > self.settings.service.status_period:
                    self.publish_status(messages.Status.READY, f"{len(inbox)} inputs waiting")
                    last_status = time.monotonic()
        finally:
            self.close()

    def _handle(self, item: Inbound, handle: Callable[[Inbound], None]) -> None:
        with self._lock:
            self.counts["accepted"] += 1
        started = time.perf_counter()
        try:
            handle(item)
        except (ValueError, MemoryError) as error:  # MessageError, CloudError, ModelError, no floor, ...
            with self._lock:
                self.counts["accepted"] -= 1
            self.reject(item, str(error))
            return
        self.last_seconds = time.perf_counter() - started

    def close(self) -> None:
        from affordcore.recording import close_recording

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
        print(
            f"[{self.service}] stopped: {self.counts['accepted']} inputs taken, {self.counts['rejected']} "
            "rejected, "
            f"{self.counts['published']} outputs published",
            flush=True,
        )
