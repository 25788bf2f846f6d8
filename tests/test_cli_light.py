"""``twin --help`` and every command's ``--help`` load no heavy library; the command index
read from the sources is what the modules register."""

import subprocess
import sys

import pytest

from twin.cli import build_parser, command_index

HEAVY = ("mujoco", "gymnasium", "numba", "scipy")

_PROBE = """
import sys
from twin.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(len(sys.modules), *[name for name in {heavy!r} if name in sys.modules], file=sys.stderr)
"""


# Every registered command, read from the sources as ``twin --help`` reads them.
COMMANDS = [name for commands in command_index().values() for name in commands or {}]


@pytest.mark.parametrize("argv", [["--help"], [], *([name, "--help"] for name in COMMANDS)],
                         ids=lambda argv: " ".join(argv) or "(none)")
def test_help_imports_no_heavy_library(argv):
    result = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=HEAVY), *argv], capture_output=True, text=True,
                            check=True, timeout=120)
    count, *heavy = result.stderr.strip().splitlines()[-1].split()
    assert heavy == [], f"twin {' '.join(argv)} imported {heavy}"
    assert int(count) < 400


def test_index_read_from_the_sources_is_what_the_modules_register():
    full = build_parser()
    registered = next(a for a in full._actions if a.dest == "command")
    index = command_index()
    assert all(commands for commands in index.values()), "a command module's register() could not be read"
    read = {name: help_text for commands in index.values() for name, help_text in commands.items()}
    assert list(read) == list(registered.choices)
    helps = {action.dest: action.help for action in registered._choices_actions}
    assert read == helps


def test_a_command_line_registers_only_its_commands_module():
    parser = build_parser(["predict", "--tensions", "1,1,1,1"])
    choices = next(a for a in parser._actions if a.dest == "command").choices
    # Every command is listed; the others stand in with no arguments of their own.
    assert list(choices) == list(next(a for a in build_parser()._actions if a.dest == "command").choices)
    assert any(a.dest == "tensions" for a in choices["predict"]._actions)
    assert all(a.dest == "help" for a in choices["sim"]._actions)
