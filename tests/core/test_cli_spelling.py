"""One spelling of the output flag on every command, and errors that name the sub-command (issue 15, item 7).

Every command that writes takes ``-o``/``--out`` (the spellings of earlier versions, ``--output`` and
``run``'s ``--out-dir``, still work); an argument a command does not know is refused in one line naming
the command (``graphpos run: error: unrecognized arguments: --foo``), as is an error while it runs
(``graphpos import plaza: error: ...``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from graphpos.cli import build_parser, main

#: The commands that write nothing (they print).
READ_ONLY = {"scenarios", "info", "estimators", "ranging table1", "ranging check", "ranging show", "replay"}
#: The older spelling each writing command still takes (``--output`` unless named here; None: a command
#: newer than the old spellings).
OLD_SPELLING = {"run": "--out-dir", "live": None, "plan-layout": None}


def leaf_commands() -> dict[str, argparse.ArgumentParser]:
    """Every sub-command (``run``, ``import plaza`` ...) and its parser."""
    found = {}

    def walk(parser: argparse.ArgumentParser, prefix: tuple[str, ...]) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            found[" ".join(prefix)] = parser
        for action in subs:
            for name, child in action.choices.items():
                walk(child, (*prefix, name))

    walk(build_parser(), ())
    return found


def minimal_argv(command: str, parser: argparse.ArgumentParser) -> list[str]:
    """``command`` with a value for every required argument (argparse checks those before unknown ones)."""
    argv = command.split()
    for action in parser._actions:
        if action.required and not action.option_strings:
            argv.append("1")
        elif action.required:
            argv += [action.option_strings[0], "1"]
    return argv


COMMANDS = leaf_commands()
WRITERS = sorted(set(COMMANDS) - READ_ONLY)


def test_the_read_only_commands_are_what_they_say():
    assert READ_ONLY <= set(COMMANDS)
    for command in READ_ONLY:
        assert not [a for a in COMMANDS[command]._actions if a.dest == "output"], command


@pytest.mark.parametrize("command", WRITERS)
def test_every_writing_command_takes_dash_o_and_dash_dash_out(command):
    outputs = [a for a in COMMANDS[command]._actions if a.dest == "output"]
    assert len(outputs) == 1, command
    option = outputs[0]
    assert option.required and option.option_strings[:2] == ["-o", "--out"], option.option_strings
    old = OLD_SPELLING.get(command, "--output")
    assert option.option_strings[2:] == ([old] if old else [])
    others = [s for a in COMMANDS[command]._actions if a is not option for s in a.option_strings if s.startswith("--out")]
    assert not others, f"{command}: another output spelling {others}"
    argv = minimal_argv(command, COMMANDS[command])
    i = argv.index("-o")
    for spelling in option.option_strings:
        args = build_parser().parse_args([*argv[:i], spelling, "somewhere/out", *argv[i + 2:]])
        assert args.output == Path("somewhere/out"), spelling


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_unknown_flag_is_refused_naming_the_command(capsys, command):
    with pytest.raises(SystemExit) as exit_:
        main([*minimal_argv(command, COMMANDS[command]), "--foo"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == f"graphpos {command}: error: unrecognized arguments: --foo\n"


def test_a_missing_output_names_the_new_spelling(capsys):
    with pytest.raises(SystemExit):
        main(["run", "drive.mcap", "-e", "dr"])
    assert capsys.readouterr().err == "graphpos run: error: the following arguments are required: -o/--out/--out-dir\n"


def test_an_error_while_running_names_the_sub_command(tmp_path, capsys):
    assert main(["import", "plaza", str(tmp_path / "none.mat"), "-o", str(tmp_path / "p.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"graphpos import plaza: error: {tmp_path / 'none.mat'}: no such file") and err.count("\n") == 1
