"""The project's error types.

Every error a user can cause (a bad file, a bad option, a drive an estimator
cannot use) is a :class:`GraphposError`. The CLI prints such an error as one
line on stderr and exits with status 2; anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import math
import os
from contextlib import contextmanager
from typing import Any, Iterator


class GraphposError(Exception):
    """Base class of every error caused by the user's input."""


class DriveError(GraphposError):
    """A drive's content is invalid.

    Parameters
    ----------
    channel : str
        The channel (or map: ``tags``, ``rsus``, ``windows``) at fault.
    row : int or None
        The offending row, 0-based, where one row is at fault.
    reason : str
        What is wrong, in words a user can act on.
    source : str, optional
        The file the drive came from, when known.
    """

    def __init__(self, channel: str, row: int | None, reason: str, source: str | None = None):
        self.channel = channel
        self.row = row
        self.reason = reason
        self.source = source
        super().__init__(self._message())

    def _message(self) -> str:
        where = f"{self.source}: " if self.source else ""
        at_row = f", row {self.row}" if self.row is not None else ""
        return f"{where}channel '{self.channel}'{at_row}: {self.reason}"

    def with_source(self, source: str) -> "DriveError":
        """The same error, naming the file it came from."""
        return DriveError(self.channel, self.row, self.reason, source)


class FileFormatError(GraphposError):
    """A file cannot be read: missing, empty, truncated, corrupt or foreign."""


class ConfigError(GraphposError):
    """A configuration value or option is invalid."""


class MissingChannelError(GraphposError):
    """An estimator was given a drive that lacks a channel it needs."""


class EstimationError(GraphposError):
    """An estimator failed on valid input (e.g. an optimiser did not converge)."""


class DriveCheckError(GraphposError):
    """A drive reads but makes no sense to estimate on: it breaks a rule of
    level ``error`` of :data:`graphpos.io.checks.DRIVE_RULES` (e.g. every
    time stamp equal)."""


@contextmanager
def naming_file(path: str | os.PathLike) -> Iterator[None]:
    """Make every :class:`GraphposError` raised inside name the file ``path``.

    For checks made after a file is read (an estimator refusing the drive, a
    config value out of range), so that the one line the user sees names the
    file at fault. An error that already names it is left as it is.
    """
    try:
        yield
    except DriveError as exc:
        if exc.source is None:
            raise exc.with_source(str(path)) from None
        raise
    except GraphposError as exc:
        if str(path) in str(exc):
            raise
        raise renamed(exc, f"{path}: {exc}") from None


def is_finite_number(value: Any) -> bool:
    """Whether a value a user gave (a JSON, TOML or command-line value) is a finite int or float; JSON's true
    and false are not numbers here."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def renamed(exc: GraphposError, message: str) -> GraphposError:
    """``exc`` with ``message``: the same class and attributes, its constructor not called (some take more
    than a message: :class:`~graphpos.profile.ImplausibleProfileError`)."""
    out = type(exc).__new__(type(exc))
    out.__dict__.update(exc.__dict__)
    out.args = (message,)
    return out
