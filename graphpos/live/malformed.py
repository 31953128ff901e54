"""The one error a live message can have: it cannot be used as it is."""

from __future__ import annotations


class MalformedMessage(ValueError):
    """A live message that cannot be used: not JSON, an unknown channel or
    topic, a missing, mistyped or out-of-range field, an unknown tag or RSU.

    Live mode counts and logs it and goes on (never fatal). ``kind`` is a
    short category for the counters (``json``, ``channel``, ``field``,
    ``id`` ...); the message says what is wrong, in one line. ``seq`` is the
    message's sequence number where it could be read (so that it is not
    counted lost).
    """

    def __init__(self, kind: str, reason: str, seq: int | None = None):
        super().__init__(reason)
        self.kind = kind
        self.seq = seq
