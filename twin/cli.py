"""The ``twin`` command: thin; each subcommand is a call into the library.

Subcommands live beside the code they drive: each module in ``COMMAND_MODULES`` has a
``register(subparsers)`` that adds its parsers and sets ``func`` (returns an exit code).

Only the module of the command being run is imported: the others' command names and one-line
helps are read from their sources (the ``add_parser`` calls of their ``register``), so ``twin
--help`` and ``twin CMD --help`` load neither MuJoCo nor Numba unless CMD's own module does.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import os
import sys
import warnings
from pathlib import Path

from twin.cliargs import UsageError, values_as_arguments
from twin.data.dataset import DatasetError, DatasetWarning
from twin.params import ParameterError
from twin.resources import NativeBuildError

COMMAND_MODULES = [
    "twin.rod.commands",
    "twin.force.commands",
    "twin.sim.commands",
    "twin.device.commands",
    "twin.device.igtl_server",
    "twin.experiments.commands",
    "twin.discrepancy.commands",
    "twin.dynamics.commands",
    "twin.dynamics.shadow",
    "twin.control.commands",
    "twin.tuning",
    "twin.bench",
    "twin.demo",
    "twin.rosbag",
    "twin.data.importer",
]


class _Parser(argparse.ArgumentParser):
    """Usage mistakes in one line, naming the argument and value, and where the usage is."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``twin`` parser for the command line ``argv``: only the module of the command it names is
    imported and registers its parsers, the other commands stand in by name and help. Without
    ``argv`` (or when its command is not found in the sources), every module registers."""
    parser = _Parser(
        prog="twin",
        description="Digital twin of a tendon-driven flexible endoscope and its rig.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    index = command_index()
    chosen = None if argv is None else next((word for word in argv if not word.startswith("-")), "")
    everything = chosen is None or (chosen and not any(chosen in (commands or {}) for commands in index.values()))
    for name in COMMAND_MODULES:
        commands = index[name]
        if everything or commands is None or chosen in commands:
            importlib.import_module(name).register(sub)
        else:
            for command, help_text in commands.items():
                sub.add_parser(command, help=help_text)
    return parser


def _module_source(name: str) -> Path:
    """Where a ``twin.*`` module's source is, found without importing its package."""
    base = Path(__file__).resolve().parent.joinpath(*name.split(".")[1:])
    return base / "__init__.py" if base.is_dir() else base.with_suffix(".py")


def command_index() -> dict[str, dict[str, str | None] | None]:
    """For each of ``COMMAND_MODULES``, the commands its ``register(sub)`` adds, with their one-line
    help, read from its source: the ``sub.add_parser("NAME", help="...")`` calls on its first
    argument. None for a module whose commands cannot be read so (it is then always imported)."""
    index: dict[str, dict[str, str | None] | None] = {}
    for name in COMMAND_MODULES:
        try:
            tree = ast.parse(_module_source(name).read_text())
        except (OSError, SyntaxError):
            index[name] = None
            continue
        commands: dict[str, str | None] = {}
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and node.name == "register" and node.args.args:
                sub = node.args.args[0].arg
                for call in ast.walk(node):
                    if (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                            and call.func.attr == "add_parser" and isinstance(call.func.value, ast.Name)
                            and call.func.value.id == sub and call.args
                            and isinstance(call.args[0], ast.Constant) and isinstance(call.args[0].value, str)):
                        help_text = next((kw.value.value for kw in call.keywords if kw.arg == "help"
                                          and isinstance(kw.value, ast.Constant) and isinstance(kw.value.value, str)),
                                         None)
                        commands[call.args[0].value] = help_text
        index[name] = commands or None
    return index


_format_warning = warnings.formatwarning


def _format(message, category, filename, lineno, line=None) -> str:
    """Dataset warnings as one line for the operator (they name file and row); others as Python's."""
    if issubclass(category, DatasetWarning):
        return f"twin: warning: {message}\n"
    return _format_warning(message, category, filename, lineno, line)


def _os_error(args: argparse.Namespace, exc: OSError) -> str:
    """An I/O error in one line, naming the argument whose path it is when one is (``--out DIR``)."""
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    if not paths:
        return str(exc)
    for failing in reversed(paths):
        for name, value in vars(args).items():
            if isinstance(value, (str, os.PathLike)) and value and (
                    failing == str(value) or failing.startswith((f"{value}/", f"{value}."))):
                return f"--{name.replace('_', '-')} {value}: {exc.strerror or exc} ({failing})"
    return f"{' -> '.join(paths)}: {exc.strerror or exc}"


def main(argv: list[str] | None = None) -> int:
    """Run one command; bad input and failing files end in one line on stderr, not a traceback.

    Returns:
        The command's exit code; 2 for a bad parameter, argument or dataset, 1 for a file that cannot
        be read or written, a native part that cannot be built or a twin that diverged, 130 on
        Ctrl-C. Called without ``argv`` (the ``twin`` command itself), a Ctrl-C ends the process at
        once instead of returning, without the interpreter's teardown.
    """
    argv = values_as_arguments(sys.argv[1:] if argv is None else list(argv))
    args = build_parser(argv).parse_args(argv)
    warnings.formatwarning = _format
    code = _run_command(args)
    if code == 130 and argv is None:
        # Ctrl-C on the command line: gone now. Tearing the interpreter down (MuJoCo, SciPy and
        # the rest) takes seconds on a loaded machine, and everything measured is on disk already.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _run_command(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"twin: parameter error: {exc}", file=sys.stderr)
        return 2
    except UsageError as exc:
        print(f"twin {args.command}: {exc}", file=sys.stderr)
        return 2
    except DatasetError as exc:
        print(f"twin: dataset error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        # The library's ValueErrors name the argument and the value it refuses; TWIN_DEBUG=1
        # shows the traceback of one that is a bug instead.
        if os.environ.get("TWIN_DEBUG"):
            raise
        print(f"twin {args.command}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"twin {args.command}: {_os_error(args, exc)}", file=sys.stderr)
        return 1
    except NativeBuildError as exc:
        # No compiler, or a build that failed: what to install, or the compiler's own output.
        print(f"twin: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("twin: interrupted", file=sys.stderr)
        return 130
    except RuntimeError as exc:
        # A twin that diverged under a command with nothing of its own to add (no dataset to
        # resume): one line. Looked up, not imported, so that commands without the twin load no
        # MuJoCo.
        plant = sys.modules.get("twin.sim.plant")
        if plant is None or not isinstance(exc, plant.SimulationError):
            raise
        print(f"twin {args.command}: the twin diverged ({exc})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
