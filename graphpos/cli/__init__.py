"""The ``graphpos`` command.

Each command group lives in its own module with a ``register(subparsers)``
function that adds its sub-commands (each with ``set_defaults(func=...)``).
A user mistake (any :class:`~graphpos.errors.GraphposError`, a missing or
unreadable file) prints one line on stderr and exits with status 2; argparse
does the same for bad options.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from graphpos import __version__
from graphpos.errors import GraphposError

#: Command-group modules, in the order their commands appear in --help.
_COMMAND_MODULES = (
    "graphpos.cli.sim",
    "graphpos.cli.drives",
    "graphpos.cli.ranging",
    "graphpos.cli.estimators",
    "graphpos.cli.calibrate",
    "graphpos.cli.evaluation",
    "graphpos.cli.faults",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, status 2
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


def one_line(text: str) -> str:
    """``text`` with every character that is not printable (newline, tab, escape, a byte of a file
    name that is not UTF-8) shown escaped as ``repr`` shows it, so that a message stays one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def error_line(command: str, message: str) -> str:
    """The one line a command prints on stderr for an error."""
    return f"graphpos {command}: error: {one_line(message)}"


def warning_line(command: str, message: str) -> str:
    """The line a command prints on stderr for a warning (e.g. a drive check, :mod:`graphpos.io.checks`)."""
    return f"graphpos {command}: warning: {one_line(message)}"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="graphpos", description="Vehicle positioning where GNSS is denied.")
    parser.add_argument("--version", action="version", version=f"graphpos {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for module_name in _COMMAND_MODULES:
        importlib.import_module(module_name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except GraphposError as exc:
        print(error_line(args.command, str(exc)), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"graphpos {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`graphpos scenarios --json | head`): stop
        # quietly, as Unix tools do, without a second error at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
