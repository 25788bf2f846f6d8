"""Argument helpers shared by the subcommands (parameters, poses, devices, the twin's hidden settings,
vectors, run folders, user errors)."""

from __future__ import annotations

import argparse
import contextlib
import datetime
import re
import signal
import threading
from pathlib import Path
from typing import Iterator

import numpy as np

from twin.checks import finite_vector
from twin.params import ParameterError, Params, load_params, parse_override
from twin.robots import DEFAULT_ROBOT, robot_path
from twin.pose import base_rotation_from, matrix_to_quat

__all__ = ["DEFAULT_DEVICE", "UsageError", "add_device_arg", "add_param_args", "add_pose_args", "add_twin_set_arg", "count",
           "new_run_folder", "nonnegative", "open_device_arg", "params_from_args", "pose_overrides", "positive",
           "sigterm_event", "twin_params", "values_as_arguments", "vector"]

# The device a command runs on unless told otherwise: the twin.
DEFAULT_DEVICE = "sim://"


class UsageError(Exception):
    """A user's mistake the command names in one line (argument and value); exit code 2."""


# A value that starts with a minus sign: -1, -0.5, -.5, -1e-3, -1,0,0.
_NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d)")


def values_as_arguments(argv: list[str]) -> list[str]:
    """``--flag -1,0`` → ``--flag=-1,0``: argparse takes a word starting with ``-`` for an option,
    so negative numbers after an option would otherwise need the ``=`` form."""
    out: list[str] = []
    for word in argv:
        if out and _NEGATIVE_VALUE.match(word) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={word}"
        else:
            out.append(word)
    return out


def positive(text: str) -> float:
    """An argparse type: a finite number > 0."""
    return _at_least(text, float, 0.0, inclusive=False)


def nonnegative(text: str) -> float:
    """An argparse type: a finite number >= 0."""
    return _at_least(text, float, 0.0)


def count(text: str) -> int:
    """An argparse type: a whole number >= 0 (seeds, counts)."""
    return _at_least(text, int, 0)


def _at_least(text: str, kind: type, low: float, *, inclusive: bool = True):
    """``text`` read as ``kind`` (float: finite), refused below ``low`` (or at it)."""
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected {'a whole number' if kind is int else 'a number'}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: must be finite")
    if value < low or (value == low and not inclusive):
        raise argparse.ArgumentTypeError(f"{text!r}: must be {'>=' if inclusive else '>'} {low:g}")
    return value


@contextlib.contextmanager
def sigterm_event() -> Iterator[threading.Event]:
    """An event that SIGTERM sets, for a command that serves until Ctrl-C or SIGTERM; the previous
    handler is back on exit. SIGTERM is the way for scripts and services: a job a non-interactive
    shell starts in the background, or a child of a process inside system(3), has SIGINT ignored."""
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    try:
        yield stop
    finally:
        signal.signal(signal.SIGTERM, previous)


def new_run_folder(parent: str | Path, name: str) -> Path:
    """A fresh ``name-YYYYmmdd-HHMMSS`` folder under ``parent`` (``runs/`` by convention: commands
    never write into tracked folders by default); runs started in the same second get ``-2``,
    ``-3``, ... (``mkdir`` either creates a folder or fails, so two never share one)."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    stamp = f"{name}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    for n in range(1, 1000):
        folder = parent / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir()
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{parent}: a thousand {stamp} run folders already exist")


def vector(n: int | None):
    """An argparse type: ``"a,b,c"`` → float array of length ``n`` (any length for None: one
    entry per tendon, checked by the command against the robot)."""

    wanted = "one or more" if n is None else str(n)

    def parse(text: str) -> np.ndarray:
        try:
            values = [float(x) for x in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {wanted} comma-separated numbers") from None
        try:
            return finite_vector("value", values, len(values) if n is None else n)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected {wanted} finite comma-separated numbers") from None

    parse.__name__ = f"vector{n or ''}"
    return parse


def add_param_args(parser: argparse.ArgumentParser, *, robot: bool = True) -> None:
    """``--robot NAME`` or ``--params FILE``, and ``--set KEY=VALUE`` on top. ``robot=False`` for a
    command that declares its own ``--robot``."""
    if robot:
        group = parser.add_mutually_exclusive_group()
        group.add_argument("--robot", metavar="NAME", default=None,
                           help="a robot of the zoo, models/NAME/ (default endoscope; see models/README.md)")
        group.add_argument("--params", metavar="FILE", help="parameter file (instead of --robot)")
    else:
        parser.add_argument("--params", metavar="FILE", help="parameter file (instead of --robot)")
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


def robot_name(args: argparse.Namespace) -> str:
    """The name of the robot a command runs with: ``--robot``, else the ``--params`` file's
    name, else the default robot."""
    if getattr(args, "robot", None):
        return args.robot
    return Path(args.params).stem if getattr(args, "params", None) else DEFAULT_ROBOT


def params_from_args(args: argparse.Namespace) -> Params:
    """The parameter set of ``--robot`` or ``--params``, and ``--set``, with ``--pose``/``--base-quat``
    where the command takes them.

    Raises:
        ParameterError: a bad file or value; also a ``--params`` file that cannot be read.
        UsageError: no such ``--robot``.
    """
    robot = getattr(args, "robot", None)
    path = args.params
    if robot is not None:
        try:
            path = robot_path(robot)
        except ValueError as exc:
            raise UsageError(f"--robot {robot}: {exc}") from None
    try:
        params = load_params(path, overrides=args.overrides)
    except OSError as exc:
        raise ParameterError(f"--params {args.params}: cannot read it ({exc.strerror or exc})") from None
    pose = pose_overrides(args)
    return params.replace(pose, source="command line") if pose else params


def add_device_arg(parser: argparse.ArgumentParser, *, default: str | None = DEFAULT_DEVICE,
                   help: str | None = None) -> None:
    """``--device URL``: what the command runs on (:func:`twin.driver.open_device`), the twin unless
    told otherwise; ``default=None`` for a command that runs on a device only when given one."""
    schemes = ("sim:// (the twin), serial:///dev/ttyACM0 (the rig), socket://HOST:PORT or rfc2217://HOST:PORT "
               "(a board over the network)")
    parser.add_argument("--device", default=default, metavar="URL",
                        help=help or f"device URL: {schemes}; default {default}")


def add_twin_set_arg(parser: argparse.ArgumentParser, *, help: str | None = None) -> None:
    """``--twin-set KEY=VALUE`` (repeatable), into ``args.twin_overrides``: a hidden change of the
    simulated rig that the model does not know (:func:`twin_params`)."""
    parser.add_argument("--twin-set", dest="twin_overrides", action="append", default=[], metavar="KEY=VALUE",
                        help=help or "sim:// only: change the simulated rig but not the model (a hidden effect, e.g. "
                        "effects.tendon_friction_coeff=0.3), repeatable")


def twin_params(args: argparse.Namespace, params: Params) -> Params:
    """The parameter set the device is built with: ``params``, with ``--twin-set`` on ``sim://``.

    Raises:
        UsageError: ``--twin-set`` on another device, or a bad key or value (the argument named).
    """
    overrides = getattr(args, "twin_overrides", None) or []
    if not overrides:
        return params
    device = getattr(args, "device", None)
    if not (device or "").startswith("sim://"):
        raise UsageError(f"--twin-set {overrides[0]}: applies to sim:// only, not --device {device}")
    try:
        return params.replace(dict(parse_override(o) for o in overrides), source="twin-set (hidden)")
    except ParameterError as exc:
        raise UsageError(f"--twin-set: {exc}") from None


def open_device_arg(url: str, **kwargs):
    """:func:`twin.driver.open_device` for a ``--device`` argument; a bad URL is a
    :class:`UsageError` naming it."""
    from twin.driver import open_device

    try:
        return open_device(url, **kwargs)
    except ValueError as exc:
        raise UsageError(f"--device {url}: {exc}") from None
