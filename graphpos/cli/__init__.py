"""The ``graphpos`` command.

Each command group lives in its own module with a ``register(subparsers)``
function that adds its sub-commands (each with ``set_defaults(func=...)``);
:data:`COMMANDS` names every command's module and one-line help, so that a
run imports only the module of its command (``graphpos --help`` none of
them, nor numpy).
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

#: Every command, in the order of ``--help``: the command-group module that registers it and its one-line
#: help (the list of ``graphpos --help``; the module's ``add_parser`` takes it from here).
COMMANDS: dict[str, tuple[str, str]] = {
    "scenarios": ("graphpos.cli.sim", "list the simulated scenarios"),
    "simulate": ("graphpos.cli.sim", "simulate a drive into an MCAP file"),
    "info": ("graphpos.cli.drives", "summarise a drive file"),
    "import": ("graphpos.cli.drives", "import a recorded dataset as a drive file"),
    "ranging": ("graphpos.cli.ranging", "RSS -> distance models and range calibration"),
    "estimators": ("graphpos.cli.estimators", "list the estimators"),
    "run": ("graphpos.cli.estimators", "run estimators over a drive"),
    "calibrate": ("graphpos.cli.calibrate", "find a drive's sensor profile (biases, scales, noise) without its truth"),
    "evaluate": ("graphpos.cli.evaluation", "run estimators over drives and write a comparison report"),
    "reproduce": ("graphpos.cli.evaluation", "reproduce the papers' tables on simulated drives (and real data)"),
    "layout-study": ("graphpos.cli.evaluation", "RMS error against number of tags (how few tags suffice)"),
    "plan-layout": ("graphpos.cli.plan", "the cheapest tag layout whose error meets a target (by the bound, then simulation)"),
    "fault-study": ("graphpos.cli.faults", "every estimator through every injected fault: error, recovery, health"),
    "live": ("graphpos.cli.live", "run online estimators on measurements as they arrive; serve them to Foxglove"),
    "replay": ("graphpos.cli.live", "send a recorded drive as a live feed (for `graphpos live`)"),
}


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


def estimator_names(values: list[str]) -> list[str]:
    """The estimator names of repeated ``-e`` options, each of which may be a comma-separated list
    (``-e fusion-ekf,dr -e graph-batch``), in order, without blanks."""
    return [n.strip() for v in values for n in v.split(",") if n.strip()]


def progress_line(command: str, message: str) -> None:
    """Say on stderr what a long step is doing, when stderr is a terminal (a person waiting; logs and pipes stay clean)."""
    if sys.stderr.isatty():
        print(f"graphpos {command}: {one_line(message)}", file=sys.stderr, flush=True)


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


class _Commands(argparse._SubParsersAction):
    """The sub-commands of ``graphpos``: each one's help is its entry of :data:`COMMANDS`."""

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        return super().add_parser(name, help=COMMANDS[name][1], **kwargs)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``graphpos``.

    Parameters
    ----------
    command : str, optional
        The command to be run: only the module registering it is imported
        and its commands' parsers built; every other command gets a parser
        without arguments, there for ``--help`` and the list of choices
        (none for a name that is not a command). None: every command's
        parser, in full.
    """
    parser = _Parser(prog="graphpos", description="Vehicle positioning where GNSS is denied.")
    parser.add_argument("--version", action="version", version=f"graphpos {__version__}")
    parser.register("action", "parsers", _Commands)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_CommandParser)
    wanted = None if command is None else COMMANDS.get(command, ("",))[0]
    registered = set()
    for name, (module_name, _) in COMMANDS.items():
        if wanted is not None and module_name != wanted:
            sub.add_parser(name)
        elif module_name not in registered:  # its commands, this one first (they follow each other in COMMANDS)
            importlib.import_module(module_name).register(sub)
            registered.add(module_name)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(next((arg for arg in argv if not arg.startswith("-")), ""))
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
