"""The ``graphpos`` command.

Each command group lives in its own module with a ``register(subparsers)``
function that adds its sub-commands (each with ``set_defaults(func=...)``).
A user mistake (any :class:`~graphpos.errors.GraphposError`, a missing or
unreadable file) prints one line on stderr and exits with status 2; argparse
does the same for bad options. Every line names the sub-command
(``graphpos run: error: unrecognized arguments: --foo``, ``graphpos import
plaza: error: ...``).

Every command that writes takes its output path as ``-o``/``--out``
(:func:`add_output_option`); the spellings of earlier versions
(``--output``, ``run``'s ``--out-dir``) still work.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

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
    "graphpos.cli.plan",
    "graphpos.cli.faults",
    "graphpos.cli.live",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, status 2
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


class _CommandParser(_Parser):
    """The parser of a sub-command: it refuses arguments it does not know itself (so that the error names
    the sub-command, not ``graphpos``) and records its name (``run``, ``import plaza``) as ``args.command``
    (the innermost sub-command's, which parses first)."""

    def parse_known_args(self, args=None, namespace=None):
        parsed, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        if not hasattr(parsed, "command"):
            parsed.command = self.prog.removeprefix("graphpos ")
        return parsed, extras


#: Help of an output folder's ``-o``.
OUTPUT_FOLDER_HELP = ("output folder (created if absent; an earlier output of graphpos there is replaced, a folder "
                      "holding other files refused)")


def add_output_option(p: argparse.ArgumentParser, metavar: str, help: str, *aliases: str) -> None:
    """``-o``/``--out`` (``args.output``, a Path), required: the one spelling of the output path on every
    command; ``aliases``: the spellings of earlier versions, still accepted."""
    p.add_argument("-o", "--out", *aliases, dest="output", type=Path, required=True, metavar=metavar, help=help)


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
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_CommandParser)
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
