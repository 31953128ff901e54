"""A command imports only what it uses (issue 19, item 3).

``graphpos --help`` imports no command module and no numpy; ``graphpos info`` none of the other commands'
modules, nor the estimators' or the simulator's libraries. Each is checked in a fresh interpreter, by the
modules it holds in ``sys.modules`` once the command has run.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from graphpos.cli import COMMANDS, build_parser
from graphpos.io import write_drive
from graphpos.sim import simulate

#: What no reading command needs: the estimators, the simulator (``info`` checks a drive's RSS environment
#: against ``graphpos.sim.rss``, but simulates nothing), plots, geodesy, config files.
HEAVY = ("gtsam", "scipy", "matplotlib", "pymap3d", "yaml", "filters", "graphpos.graph", "graphpos.sim.simulate", "eval")


def modules_after(argv: list[str]) -> set[str]:
    """The modules a fresh interpreter holds after ``graphpos ARGV`` (whatever its exit status)."""
    code = ("import json, sys\nfrom graphpos.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "print(json.dumps(sorted(sys.modules)), file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True)
    return set(json.loads(done.stderr.splitlines()[-1]))


def loaded(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if m in names or m.startswith(tuple(n + "." for n in names)))


def test_help_imports_no_command_module_nor_numpy():
    modules = modules_after(["--help"])
    command_modules = tuple(dict.fromkeys(module for module, _ in COMMANDS.values()))
    assert loaded(modules, command_modules + ("numpy", "msgspec", "mcap") + HEAVY) == []


def test_info_imports_only_what_it_uses(tmp_path):
    path = tmp_path / "drive.mcap"
    write_drive(path, simulate("paper-straight", seed=0, duration_s=20.0))
    modules = modules_after(["info", str(path)])
    assert "graphpos.cli.drives" in modules and "graphpos.io.checks" in modules
    others = tuple(dict.fromkeys(module for module, _ in COMMANDS.values() if module != "graphpos.cli.drives"))
    assert loaded(modules, others + HEAVY) == []


@pytest.mark.parametrize("command", ["", "info", "run", "bogus"])
def test_the_list_of_commands_is_the_full_parsers(command):
    """``--help`` of a parser built for one command lists every command as the full parser does."""
    assert build_parser(command).format_help() == build_parser().format_help()
