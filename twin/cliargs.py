"""Argument helpers shared by the subcommands (parameters, poses, vectors)."""

from __future__ import annotations

import argparse

import numpy as np

from twin.params import ParameterError, Params, load_params
from twin.pose import base_rotation_from, matrix_to_quat

__all__ = ["add_param_args", "add_pose_args", "params_from_args", "pose_overrides", "vector"]


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


def add_pose_args(parser: argparse.ArgumentParser) -> None:
    """``--pose`` / ``--base-quat``: the clamp orientation, stored as the parameter set's
    ``rig.base_quat`` by :func:`params_from_args` (default the parameter file's)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--base-quat", type=vector(4), metavar="W,X,Y,Z",
                       help="base orientation quaternion (default the parameter set's rig.base_quat)")
    group.add_argument("--pose", choices=["up", "horizontal"], default=None,
                       help="named base orientation (default the parameter set's rig.base_quat: horizontal)")


def pose_overrides(args: argparse.Namespace) -> dict:
    """``{"rig.base_quat": [w, x, y, z]}`` for a ``--pose`` or ``--base-quat`` given, else ``{}``."""
    quat = getattr(args, "base_quat", None)
    if quat is None and getattr(args, "pose", None) is not None:
        quat = matrix_to_quat(base_rotation_from(pose=args.pose))
    return {} if quat is None else {"rig.base_quat": [float(q) for q in quat]}


def params_from_args(args: argparse.Namespace) -> Params:
    """The parameter set of ``--params`` and ``--set``, with ``--pose``/``--base-quat`` where the
    command takes them.

    Raises:
        ParameterError: a bad file or value; also a ``--params`` file that cannot be read.
    """
    try:
        params = load_params(args.params, overrides=args.overrides)
    except OSError as exc:
        raise ParameterError(f"--params {args.params}: cannot read it ({exc.strerror or exc})") from None
    pose = pose_overrides(args)
    return params.replace(pose, source="command line") if pose else params
