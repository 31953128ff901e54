"""Send a recorded drive as a live feed: each reading at its recorded arrival time, optionally damaged.

The drive's measurements (never its truth) go out in the order a live
system would have received them (:meth:`graphpos.drive.Drive.measurements`
by arrival: a late RFID reading after the IMU samples that overtook it,
with its own ``arrival_s``), one message each in the live wire format
(:mod:`graphpos.live.protocol`) with a sequence number, then the
end-of-drive message (three times, so that one loss does not leave the
receiver waiting). ``speed`` 1 sends in real time, 10 ten times faster,
0 as fast as the link takes them.

:class:`Damage` makes the network a real one: each message is lost,
garbled, duplicated or held back behind the next 1 to 3 with the given
probabilities (seeded), and the counts of what was done are returned so a
test can check the receiver counted them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from graphpos.drive import Drive
from graphpos.errors import ConfigError
from graphpos.live.protocol import LIVE_CHANNELS, encode, encode_end

#: Ways a message is garbled: (name, whether its seq can still be read).
GARBLINGS = (("cut", False), ("not_a_number", True), ("unknown_channel", True), ("bytes", False))
_PROGRESS_EVERY_S = 5.0


@dataclass(frozen=True)
class Damage:
    """Probabilities (0-1) of what happens to each message, and the seed."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    malformed: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder", "malformed"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ConfigError(f"--{name} must be a probability from 0 to 1, got {p}")


@dataclass
class ReplayCounts:
    """What the replay sent and did: ``messages`` the drive's measurements, ``sent`` the datagrams that carried
    them (duplicates counted, lost ones not; the end-of-drive message, sent three times, not counted)."""

    messages: int = 0
    sent: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    malformed: dict[str, int] = field(default_factory=dict)

    @property
    def malformed_unreadable(self) -> int:
        """Garbled messages whose seq cannot be read (the receiver counts them lost too)."""
        readable = dict(GARBLINGS)
        return sum(n for kind, n in self.malformed.items() if not readable[kind])

    def to_dict(self) -> dict:
        return {"messages": self.messages, "sent": self.sent, "lost": self.lost, "duplicated": self.duplicated,
                "reordered": self.reordered, "malformed": dict(self.malformed), "malformed_unreadable": self.malformed_unreadable}


def _garble(payload: bytes, kind: str, rng: np.random.Generator) -> bytes:
    if kind == "cut":
        return payload[: max(1, len(payload) // 2)]
    if kind == "bytes":
        return rng.integers(0, 256, size=len(payload), dtype=np.uint8).tobytes()
    body = json.loads(payload)
    if kind == "not_a_number":
        body["t_s"] = str(body["t_s"])
    else:
        body["channel"] = "x" + body["channel"]
    return json.dumps(body).encode()


def _damaged(payload: bytes, damage: Damage | None, rng: np.random.Generator, counts: ReplayCounts, held: list) -> list[bytes]:
    """What goes out now for one message (nothing when lost or held back: ``held`` gets [messages to wait, payload])."""
    if damage is None:
        return [payload]
    if rng.random() < damage.loss:
        counts.lost += 1
        return []
    if rng.random() < damage.malformed:
        kind = GARBLINGS[int(rng.integers(len(GARBLINGS)))][0]
        counts.malformed[kind] = counts.malformed.get(kind, 0) + 1
        payload = _garble(payload, kind, rng)
    copies = 2 if rng.random() < damage.duplicate else 1
    counts.duplicated += copies - 1
    if rng.random() < damage.reorder:
        counts.reordered += 1
        held.extend([int(rng.integers(1, 4)), payload] for _ in range(copies))
        return []
    return [payload] * copies


def replay(drive: Drive, send: Callable[[bytes], None], speed: float = 1.0, damage: Damage | None = None,
           log: Callable[[str], None] | None = None) -> ReplayCounts:
    """Send ``drive`` (without its truth) through ``send``; the counts of what was sent and done.

    Parameters
    ----------
    drive : Drive
    send : callable
        Sends one message (:func:`graphpos.live.sources.sender`).
    speed : float
        Time factor (1: real time; 0: no pacing).
    damage : Damage, optional
    log : callable, optional
        Takes a progress line every few seconds.
    """
    if not (speed >= 0.0 and np.isfinite(speed)):
        raise ConfigError(f"--speed must be 0 (as fast as possible) or a positive factor, got {speed}")
    view = drive.without_truth()
    channels = [c for c in LIVE_CHANNELS if view.has(c)]
    if not channels:
        raise ConfigError(f"drive '{drive.name}' has no measurements to send (only truth, or nothing)")
    total = sum(len(view.channels[c]) for c in channels)
    counts = ReplayCounts()
    rng = np.random.default_rng(damage.seed if damage else 0)
    held: list[list] = []  # [messages still to pass it, payload]
    t0_wall = time.monotonic()
    first_s = None
    next_progress = t0_wall + _PROGRESS_EVERY_S

    def out(payload: bytes) -> None:
        send(payload)
        counts.sent += 1

    seq = 0
    for seq, m in enumerate(view.measurements(channels, by="arrival")):
        counts.messages += 1
        if first_s is None:
            first_s = m.arrival_s
        if speed > 0:
            wait = t0_wall + (m.arrival_s - first_s) / speed - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        if log is not None and time.monotonic() >= next_progress:
            next_progress += _PROGRESS_EVERY_S
            log(f"replay: {counts.messages}/{total} messages, drive time {m.arrival_s - first_s:.1f} s")
        for payload in _damaged(encode(m, seq), damage, rng, counts, held):
            out(payload)
        for item in list(held):  # after this message: one held back by k arrives behind the next k
            item[0] -= 1
            if item[0] < 0:
                held.remove(item)
                out(item[1])
    for _, payload in held:
        out(payload)
    end = encode_end(seq + 1)
    for _ in range(3):
        send(end)
        time.sleep(0.05)
    return counts
