"""The zoo of robots: each robot is data, a folder ``models/<name>/`` holding its parameter file
``<name>.toml`` (every value with its source), the generated MJCF ``<name>.xml``, a README
with the parameter table and a CHANGELOG, in the manner of MuJoCo Menagerie.

A new robot is a new folder: copy a parameter file, change what differs (with sources) and run
``python -m twin.sim.modelfiles``. Every command takes ``--robot NAME`` (or ``--params FILE``).

Example:
    >>> from twin.robots import load_robot, robot_names
    >>> "endoscope" in robot_names()
    True
    >>> load_robot("three-tendon").tendons.count
    3
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping

from twin.params import DEFAULT_PARAMS_PATH, Params, load_params

__all__ = ["DEFAULT_ROBOT", "MODELS_DIR", "description", "load_robot", "robot_names", "robot_path"]

MODELS_DIR = DEFAULT_PARAMS_PATH.parent.parent
# The thesis endoscope: the robot every command uses unless told otherwise.
DEFAULT_ROBOT = DEFAULT_PARAMS_PATH.stem


def robot_names() -> list[str]:
    """The robots in ``models/``, the default first, then by name."""
    names = sorted(p.name for p in MODELS_DIR.iterdir() if (p / f"{p.name}.toml").is_file())
    return sorted(names, key=lambda n: n != DEFAULT_ROBOT)


def robot_path(name: str) -> Path:
    """The parameter file of robot ``name``.

    Raises:
        ValueError: no such robot (the message lists those there are).
    """
    path = MODELS_DIR / name / f"{name}.toml"
    if "/" in name or name.startswith(".") or not path.is_file():
        raise ValueError(f"robot {name!r}: expected one of {', '.join(robot_names())}")
    return path


def description(name: str) -> str:
    """What robot ``name`` is: the first comment line of its parameter file, ``# name: …``."""
    first = robot_path(name).read_text().split("\n", 1)[0]
    return first.removeprefix("#").strip().removeprefix(f"{name}:").strip()


def load_robot(name: str, overrides: Iterable[str] | Mapping[str, object] = ()) -> Params:
    """Robot ``name``'s parameter set, with ``overrides`` as :func:`twin.params.load_params` takes them."""
    return load_params(robot_path(name), overrides=overrides)
