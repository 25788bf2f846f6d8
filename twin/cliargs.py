"""Argument helpers shared by the subcommands (parameters, poses, vectors)."""

from __future__ import annotations

import argparse

import numpy as np

from twin.params import ParameterError, Params, load_params
from twin.pose import base_rotation_from

__all__ = ["add_param_args", "add_pose_args", "params_from_args", "rotation_from_args", "vector"]


def vector(n: int):
    """An argparse type: ``"a,b,c"`` → float array of length ``n``."""

    def parse(text: str) -> np.ndarray:
        try:
            values = np.array([float(x) for x in text.split(",")])
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {n} comma-separated numbers") from None
        if values.size != n or not np.all(np.isfinite(values)):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {n} finite comma-separated numbers")
        return values

    parse.__name__ = f"vector{n}"
    return parse


def add_param_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", metavar="FILE", help="parameter file (default models/endoscope.toml)")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="override a parameter, e.g. --set backbone.shear_modulus_pa=3e6 (repeatable)",
    )


def add_pose_args(parser: argparse.ArgumentParser, default: str = "horizontal") -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--base-quat", type=vector(4), metavar="W,X,Y,Z", help="base orientation quaternion")
    group.add_argument("--pose", choices=["up", "horizontal"], default=None,
                       help=f"named base orientation (default {default})")
    parser.set_defaults(default_pose=default)


def params_from_args(args: argparse.Namespace) -> Params:
    """The parameter set of ``--params`` and ``--set``.

    Raises:
        ParameterError: a bad file or value; also a ``--params`` file that cannot be read.
    """
    try:
        return load_params(args.params, overrides=args.overrides)
    except OSError as exc:
        raise ParameterError(f"--params {args.params}: cannot read it ({exc.strerror or exc})") from None


def rotation_from_args(args: argparse.Namespace) -> np.ndarray:
    if args.base_quat is not None:
        return base_rotation_from(quat=args.base_quat)
    return base_rotation_from(pose=args.pose or args.default_pose)
