"""The live loop: received messages in, estimates out, as they come.

Threads: each listener (:mod:`graphpos.live.sources`) receives, and in
its thread the session decodes and checks each message, keeps the network
accounting and hands the measurement to every estimator's queue; each
estimator runs in its own worker thread, so one that falls behind lets its
queue grow and reports its lag (``lag_s``, ``queue``) instead of holding
up the input or the other estimators. The caller's thread reports the
status once a second (:meth:`LiveSession.run`).

Network behaviour (counted in :attr:`LiveSession.counts`, never fatal):

- **duplicates**: a message whose ``seq`` was already taken (or, without
  ``seq``, whose bytes equal one of the last :data:`DEDUP_WINDOW`) is dropped;
- **lost**: sequence numbers between the first and the last seen that never
  arrived intact (a message too garbled to read its ``seq`` counts here);
- **reordered**: a message with a ``seq`` below one already taken. It is
  used: a late range or fix goes to the estimators, which attach it at its
  own time (the graph, up to its ``max_delay_s``) or apply it now (a
  filter); an IMU or wheel sample older than the last one of its channel is
  dropped (``out_of_order``), because the odometry between them has
  already been integrated, and the estimators bridge the gap;
- **malformed**: counted by kind, the first ones and then every
  :data:`LOG_EVERY`-th logged, each recorded raw on ``/live/rejected``.

Arrival times: a measurement's ``arrival_s`` (the drive clock's time at
which it reached us) is its own ``arrival_s`` field when the sender gives
one, else its ``t_s``, but never earlier than that of the measurement
before it: live, nothing arrives before what has already arrived. A drive
replayed in its recorded order thus arrives exactly as ``run`` reads it.

Latency: for each measurement and estimator, from its receipt (the
kernel's stamp for UDP) to the moment the outputs it completed were
published (or its processing ended, when it completed none); reported
per estimator as p50/p95/p99 over all measurements and over those that
published (``latency_ms``, ``publish_latency_ms``), live and in the
recording (``/live/<name>/latency``, one message per measurement).
"""

from __future__ import annotations

import collections
import json
import math
import queue
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np

from graphpos.drive import Drive, Measurement
from graphpos.errors import GraphposError
from graphpos.estimate import OutputRow
from graphpos.live.feed import LiveFeed
from graphpos.live.malformed import MalformedMessage
from graphpos.live.protocol import LIVE_CHANNELS, Decoder, Received

#: Payload hashes remembered for duplicate detection without ``seq``.
DEDUP_WINDOW = 4096
#: Sequence numbers remembered for duplicate detection (older ones count as duplicates).
SEQ_WINDOW = 1 << 20
#: Malformed messages logged before thinning to one every LOG_EVERY.
LOG_FIRST = 5
LOG_EVERY = 100
#: Odometry channels whose samples must come in time order (integrated between samples).
ORDERED_CHANNELS = ("imu", "wheel")


class Output(Protocol):
    """Where estimates and status go (Foxglove, UDP, the recording)."""

    def estimate(self, name: str, row: OutputRow) -> None: ...

    def status(self, status: dict[str, Any]) -> None: ...


class Translator(Protocol):
    """Turns one received message into measurements (:class:`graphpos.live.rosbridge.RosbridgeTranslator`)."""

    def translate(self, message: dict, receipt_s: float) -> list[Measurement]: ...


def _percentiles(values_ms: list[float]) -> dict[str, float | None]:
    if not values_ms:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    arr = np.asarray(values_ms)
    p50, p95, p99 = np.percentile(arr, [50, 95, 99])
    return {"p50": float(p50), "p95": float(p95), "p99": float(p99), "max": float(arr.max())}


_END = object()


class _Worker:
    """One estimator in its own thread, fed from its queue."""

    def __init__(self, feed: LiveFeed, outputs: list[Output], record_latency: Callable[[str, Measurement, int | None, float, int], None],
                 log: Callable[[str], None]):
        self.feed = feed
        self.name = feed.name
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.status = "running"
        self.error: str | None = None
        self.processed = self.published = 0
        self.output_errors: dict[str, int] = {}
        self.latency_ms: list[float] = []
        self.publish_latency_ms: list[float] = []
        self.last_t_s: float = -math.inf
        self._busy_receipt_ns: int | None = None
        self._outputs = outputs
        self._record_latency = record_latency
        self._log = log
        self._thread = threading.Thread(target=self._loop, name=f"graphpos-live-{self.name}", daemon=True)
        self._thread.start()

    def lag_s(self) -> float:
        """How far behind the input the estimator is: the age of what it works on (0 when idle)."""
        busy = self._busy_receipt_ns
        return 0.0 if busy is None else max(0.0, (time.time_ns() - busy) * 1e-9)

    def _publish(self, rows: list[OutputRow]) -> None:
        for row in rows:
            for out in self._outputs:
                try:
                    out.estimate(self.name, row)
                except Exception as exc:  # noqa: BLE001 - a failing output never stops the estimator or the others
                    self._output_failed(out, exc)
            self.last_t_s = row.t_s
        self.published += len(rows)

    def _output_failed(self, out: Output, exc: Exception) -> None:
        key = type(out).__name__
        self.output_errors[key] = self.output_errors.get(key, 0) + 1
        if self.output_errors[key] == 1:
            self._log(f"{self.name}: publishing to {key} failed (counted from now on): {type(exc).__name__}: {exc}")

    def _loop(self) -> None:
        while True:
            item = self.queue.get()
            if item is _END:
                self._finish()
                return
            if self.status != "running":
                continue
            receipt_ns, seq, m = item
            self._busy_receipt_ns = receipt_ns
            try:
                rows = self.feed.process(m)
                self._publish(rows)
            except Exception as exc:  # noqa: BLE001 - one estimator's failure never stops the others
                self._fail(exc)
                continue
            finally:
                self._busy_receipt_ns = None
            latency_ms = (time.time_ns() - receipt_ns) * 1e-6
            self.processed += 1
            self.latency_ms.append(latency_ms)
            if rows:
                self.publish_latency_ms.append(latency_ms)
            self._record_latency(self.name, m, seq, latency_ms, len(rows))

    def _fail(self, exc: Exception) -> None:
        self.status = "failed"
        self.error = f"{type(exc).__name__}: {exc}"
        when = f"after its output at t = {self.last_t_s:.2f} s" if math.isfinite(self.last_t_s) else "before its first output"
        # a bug leaves its traceback in the log for a report; a GraphposError says what went wrong itself
        detail = "" if isinstance(exc, GraphposError) else "\n" + traceback.format_exc()
        self._log(f"{self.name} failed {when} and stops: {self.error}{detail}")

    def _finish(self) -> None:
        if self.status != "running":
            return
        try:
            estimate = self.feed.finish()
            rest = [row for row in estimate.rows() if row.t_s > self.last_t_s]
            self._publish(rest)
            self.status = "finished"
        except Exception as exc:  # noqa: BLE001
            self._fail(exc)

    def join(self, timeout_s: float | None = None) -> bool:
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def describe(self) -> dict[str, Any]:
        return {
            "status": self.status,
            **({"error": self.error} if self.error else {}),
            "processed": self.processed,
            "published": self.published,
            "queue": self.queue.qsize(),
            **({"output_errors": dict(self.output_errors)} if self.output_errors else {}),
            "lag_s": self.lag_s(),
            "last_output_t_s": self.last_t_s if math.isfinite(self.last_t_s) else None,
            "latency_ms": _percentiles(self.latency_ms),
            "publish_latency_ms": _percentiles(self.publish_latency_ms),
        }


@dataclass
class Counts:
    """The network accounting of a session."""

    received: int = 0
    accepted: int = 0
    duplicates: int = 0
    reordered: int = 0
    malformed: dict[str, int] = field(default_factory=dict)
    out_of_order: dict[str, int] = field(default_factory=dict)
    ignored: dict[str, int] = field(default_factory=dict)
    internal_errors: int = 0
    first_seq: int | None = None
    max_seq: int | None = None
    seqs_seen: int = 0

    @property
    def lost(self) -> int:
        """Sequence numbers between the first and the last seen that never arrived intact."""
        if self.first_seq is None:
            return 0
        return self.max_seq - self.first_seq + 1 - self.seqs_seen

    def to_dict(self) -> dict[str, Any]:
        return {"received": self.received, "accepted": self.accepted, "duplicates": self.duplicates, "lost": self.lost,
                "reordered": self.reordered, "malformed": dict(self.malformed), "malformed_total": sum(self.malformed.values()),
                "out_of_order": dict(self.out_of_order), "ignored": dict(self.ignored), "internal_errors": self.internal_errors}


class LiveSession:
    """Online estimators over messages as they arrive.

    Parameters
    ----------
    site : Drive
        Maps, origin and sensor set (:class:`graphpos.live.feed.LiveFeed`).
    feeds : list of LiveFeed
        The estimators, started on the site.
    outputs : list of Output
        Where each estimate row and the status go.
    recording : graphpos.live.recording.LiveRecording or None
        Records the accepted inputs, rejected messages and latencies (it is
        usually also one of ``outputs``).
    translator : Translator, optional
        Turns messages of another protocol (rosbridge) into measurements;
        default: the live wire format (:mod:`graphpos.live.protocol`).
    log : callable
        Takes one line (stderr).
    """

    def __init__(self, site: Drive, feeds: list[LiveFeed], outputs: list[Output], recording=None, translator: Translator | None = None,
                 log: Callable[[str], None] = print):
        self.counts = Counts()
        self.now_s = -math.inf
        self.ended = False
        self._decoder = Decoder(site)
        self._translator = translator
        self._recording = recording
        self._outputs = outputs
        self._log = log
        self._lock = threading.Lock()
        self._ended = threading.Event()
        self._closed = False
        self._seen_seq: set[int] = set()
        self._recent = collections.deque(maxlen=DEDUP_WINDOW)
        self._recent_set: set[int] = set()
        self._last_t = {c: -math.inf for c in ORDERED_CHANNELS}
        record = recording.latency if recording is not None else (lambda *a: None)
        self.workers = [_Worker(f, outputs, record, log) for f in feeds]

    # -- input (any thread) ---------------------------------------------------
    def receive(self, payload: bytes, receipt_ns: int, source: str) -> None:
        """Take one received message: decoded, checked and queued for each estimator in the caller's
        thread (a listener's: one hand-over fewer than an inbox would cost), never blocking on an estimator."""
        with self._lock:
            if not self._closed:
                self._handle(payload, receipt_ns, source)
                if self.ended:
                    self._ended.set()

    # -- the loop -------------------------------------------------------------
    def run(self, stop: threading.Event, status_every_s: float = 1.0, on_status: Callable[[dict], None] | None = None) -> dict[str, Any]:
        """Report the status every ``status_every_s`` until the end-of-drive message or ``stop``; finish the
        estimators (each after what it was given); the final status."""
        while not self._ended.wait(status_every_s) and not stop.is_set():
            self._emit_status(on_status)
        with self._lock:
            self._closed = True  # nothing more is taken
        for w in self.workers:
            w.queue.put(_END)
        while not all(w.join(status_every_s) for w in self.workers):
            self._emit_status(on_status)
        return self._emit_status(on_status)

    def status(self) -> dict[str, Any]:
        """Counts, the drive clock and each estimator's progress, lag and latency."""
        return {"t_s": self.now_s if math.isfinite(self.now_s) else None, "ended": self.ended, **self.counts.to_dict(),
                "estimators": {w.name: w.describe() for w in self.workers}}

    def _emit_status(self, on_status) -> dict[str, Any]:
        status = self.status()
        for out in self._outputs:
            out.status(status)
        if on_status is not None:
            on_status(status)
        return status

    # -- one message ------------------------------------------------------------
    def _reject(self, payload: bytes, exc: MalformedMessage, source: str) -> None:
        n = self.counts.malformed.get(exc.kind, 0) + 1
        self.counts.malformed[exc.kind] = n
        total = sum(self.counts.malformed.values())
        if total <= LOG_FIRST or total % LOG_EVERY == 0:
            self._log(f"malformed message from {source} ({total} so far): {exc}")
        if self._recording is not None:
            self._recording.rejected(payload, str(exc), exc.kind, source)

    def _duplicate(self, payload: bytes, seq: int | None) -> bool:
        """Whether the message was already taken; notes it as taken when not."""
        c = self.counts
        if seq is None:
            key = hash(payload)
            if key in self._recent_set:
                return True
            if len(self._recent) == self._recent.maxlen:
                self._recent_set.discard(self._recent[0])
            self._recent.append(key)
            self._recent_set.add(key)
            return False
        if seq in self._seen_seq or (c.max_seq is not None and seq <= c.max_seq - SEQ_WINDOW):
            return True
        self._seen_seq.add(seq)
        c.seqs_seen += 1
        if c.first_seq is None:
            c.first_seq = c.max_seq = seq
        elif seq < c.first_seq:
            c.first_seq = seq  # the first one seen had overtaken this one
            c.reordered += 1
        elif seq < c.max_seq:
            c.reordered += 1
        else:
            c.max_seq = seq
        if len(self._seen_seq) > 2 * SEQ_WINDOW:
            self._seen_seq = {s for s in self._seen_seq if s > c.max_seq - SEQ_WINDOW}
        return False

    def _decode(self, payload: bytes, receipt_ns: int) -> tuple[list[Measurement], int | None, bool]:
        """(measurements, seq, end) of one message; MalformedMessage when it cannot be used."""
        if self._translator is None:
            received: Received = self._decoder.decode(payload)
            return ([received.measurement] if received.measurement else []), received.seq, received.measurement is None
        try:
            message = json.loads(payload)
        except (ValueError, RecursionError) as exc:
            raise MalformedMessage("json", f"not JSON ({str(exc)[:80]})") from None
        if type(message) is dict and message.get("op") == "graphpos_end":
            return [], message.get("seq") if type(message.get("seq")) is int else None, True
        if type(message) is not dict:
            raise MalformedMessage("json", "not a JSON object")
        return self._translator.translate(message, receipt_ns * 1e-9), None, False

    def _handle(self, payload: bytes, receipt_ns: int, source: str) -> None:
        try:
            self._take(payload, receipt_ns, source)
        except Exception as exc:  # noqa: BLE001 - a bug met by one message must not end the session
            self.counts.internal_errors += 1
            if self.counts.internal_errors <= LOG_FIRST:
                self._log(f"internal error on a message from {source} (skipped): {type(exc).__name__}: {exc}\n{traceback.format_exc()}")

    def _take(self, payload: bytes, receipt_ns: int, source: str) -> None:
        c = self.counts
        c.received += 1
        try:
            measurements, seq, end = self._decode(payload, receipt_ns)
        except MalformedMessage as exc:
            if self._duplicate(payload, exc.seq):  # a garbled message sent twice is one garbled message
                c.duplicates += 1
            else:
                self._reject(payload, exc, source)
            return
        if self._duplicate(payload, seq):
            c.duplicates += 1
            return
        if end:
            self.ended = self._closed = True
            return
        c.accepted += 1
        for m in measurements:
            self._dispatch(m, receipt_ns, seq)

    def _dispatch(self, m: Measurement, receipt_ns: int, seq: int | None) -> None:
        if m.channel not in LIVE_CHANNELS:  # a mapping's truth topic: truth is for scoring only
            self.counts.ignored[m.channel] = self.counts.ignored.get(m.channel, 0) + 1
            return
        if m.channel in self._last_t:
            if m.t_s < self._last_t[m.channel]:
                self.counts.out_of_order[m.channel] = self.counts.out_of_order.get(m.channel, 0) + 1
                return
            self._last_t[m.channel] = m.t_s
        arrival_s = m.arrival_s if m.arrival_s >= self.now_s else self.now_s
        self.now_s = arrival_s
        if arrival_s != m.arrival_s:
            values = {**m.values, "arrival_s": arrival_s} if "arrival_s" in m.values else m.values
            m = m._replace(arrival_s=arrival_s, values=values)
        if self._recording is not None:
            self._recording.measurement(m)
        for w in self.workers:
            w.queue.put((receipt_ns, seq, m))
