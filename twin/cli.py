"""The ``twin`` command: thin; each subcommand is a call into the library.

Subcommands live beside the code they drive: each module in ``COMMAND_MODULES`` has a
``register(subparsers)`` that adds its parsers and sets ``func`` (returns an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from twin.cliargs import UsageError, values_as_arguments
from twin.data.dataset import DatasetError, DatasetWarning
from twin.params import ParameterError
from twin.resources import NativeBuildError

COMMAND_MODULES = [
    "twin.rod.commands",
    "twin.sim.commands",
    "twin.device.commands",
    "twin.device.igtl_server",
    "twin.experiments.commands",
    "twin.discrepancy.commands",
    "twin.dynamics.commands",
    "twin.control.commands",
    "twin.tuning",
    "twin.bench",
    "twin.demo",
    "twin.data.rosbag",
]


class _Parser(argparse.ArgumentParser):
    """Usage mistakes in one line, naming the argument and value, and where the usage is."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="twin",
        description="Digital twin of a tendon-driven flexible endoscope and its rig.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


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
        be read or written or a native part that cannot be built, 130 on Ctrl-C. Called without
        ``argv`` (the ``twin`` command itself), a Ctrl-C ends the process at once instead of
        returning, without the interpreter's teardown.
    """
    parser = build_parser()
    args = parser.parse_args(values_as_arguments(sys.argv[1:] if argv is None else list(argv)))
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


if __name__ == "__main__":
    sys.exit(main())
