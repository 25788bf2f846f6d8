"""The ``twin`` command: thin; each subcommand is a call into the library.

Subcommands live beside the code they drive: each module in ``COMMAND_MODULES`` has a
``register(subparsers)`` that adds its parsers and sets ``func`` (returns an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from twin.params import ParameterError

COMMAND_MODULES = [
    "twin.rod.commands",
    "twin.sim.commands",
    "twin.device.commands",
    "twin.experiments.commands",
    "twin.discrepancy.commands",
    "twin.control.commands",
    "twin.tuning",
    "twin.bench",
    "twin.demo",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="twin",
        description="Digital twin of a tendon-driven flexible endoscope and its rig.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ParameterError as exc:
        print(f"twin: parameter error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("twin: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
