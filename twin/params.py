"""The one parameter set of the endoscope and rig.

Loaded from ``models/endoscope/endoscope.toml`` where every value is ``{ value = ..., source = "..." }``;
the predictor (:mod:`twin.rod`) and the twin (:mod:`twin.sim`) both read it, so a change of
parameters changes both models. Units are in the field names.

Example:
    >>> p = load_params(overrides=["backbone.shear_modulus_pa=3e6"])
    >>> p.backbone.shear_modulus_pa, p.source("backbone.shear_modulus_pa")
    (3000000.0, 'override')
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

import numpy as np

from twin.board_limits import MAX_TENSION_LIMIT_N, RATED_GAIN_COUNTS_PER_N, motor_problems
from twin.effects import PER_TENDON, Key, parameter_keys
from twin.pose import HORIZONTAL_QUAT, rotation_of_quat
from twin.resources import resource_path

__all__ = [
    "DEFAULT_PARAMS_PATH",
    "ParameterError",
    "Params",
    "Backbone",
    "Tendons",
    "Discs",
    "Environment",
    "Rig",
    "Sensors",
    "Effects",
    "SimSettings",
    "SolverSettings",
    "load_params",
    "parse_override",
]

DEFAULT_PARAMS_PATH = resource_path("models") / "endoscope" / "endoscope.toml"


class ParameterError(ValueError):
    """A parameter is missing, unknown, of the wrong type or out of range; names key and value."""


# Whole-number settings are counts and strides that compiled code (MuJoCo, the solver) holds
# in a C int: larger values cannot mean anything but a typo.
_INT_MAX = 2**31 - 1


# Checks carried as field metadata: each returns an error string or None.
def _positive(x):
    return None if x > 0 else "must be > 0"


def _nonnegative(x):
    return None if x >= 0 else "must be >= 0"


def _choice(*options):
    def check(x):
        return None if x in options else f"must be one of {', '.join(repr(o) for o in options)}"

    return check


def _length(n):
    def check(x):
        return None if len(x) == n else f"must have {n} entries"

    return check


def _at_least_one(x):
    return None if len(x) >= 1 else "must have at least one entry"


def _nonzero_norm(x):
    norm = math.hypot(*x)
    return None if math.isfinite(norm) and norm > 1e-9 else "must not be all zero"


def _f(*checks, source: str | None = None, **kw):
    """A field with its checks; ``source`` is where the default comes from for a file without it."""
    return dataclasses.field(metadata={"checks": checks, "default_source": source}, **kw)


@dataclasses.dataclass(frozen=True)
class Backbone:
    """The flexible backbone: a uniform elastic rod (thesis §6-7)."""

    length_m: float = _f(_positive)
    radius_m: float = _f(_positive)
    youngs_modulus_pa: float = _f(_positive)
    shear_modulus_pa: float = _f(_positive)
    mass_kg: float = _f(_nonnegative)
    axial_stiffness_n: float = _f(_positive)
    torsion: str = _f(_choice("EJ", "GJ"))

    @property
    def area_m2(self) -> float:
        """Cross-section area A (m²)."""
        return math.pi * self.radius_m**2

    @property
    def second_moment_m4(self) -> float:
        """Area moment Ixx = Iyy of the circular section (m⁴)."""
        return math.pi * self.radius_m**4 / 4.0

    @property
    def bending_stiffness_nm2(self) -> float:
        """EI (N·m²)."""
        return self.youngs_modulus_pa * self.second_moment_m4

    @property
    def torsional_stiffness_nm2(self) -> float:
        """E(Ixx+Iyy) as the thesis's K_bt, or G·J (N·m²)."""
        modulus = self.youngs_modulus_pa if self.torsion == "EJ" else self.shear_modulus_pa
        return modulus * 2.0 * self.second_moment_m4

    @property
    def shear_stiffness_n(self) -> float:
        """GA (N)."""
        return self.shear_modulus_pa * self.area_m2



@dataclasses.dataclass(frozen=True)
class Tendons:
    """Tendon routing through the spacer discs."""

    radius_m: float = _f(_positive)
    angles_deg: tuple[float, ...] = _f(_at_least_one)
    diameter_m: float = _f(_positive)
    routing: str = _f(_choice("straight", "helical", "converging"))
    helix_turns: float = _f()
    tip_radius_m: float = _f(_nonnegative)
    pretension_n: float = _f(_nonnegative)
    # The disc (1 … discs.count, counted from the base) each tendon is anchored at: a robot with
    # tendons ending at several discs has that many segments. Empty: every tendon ends at the tip.
    end_discs: tuple[float, ...] = _f(default=(), source="default: every tendon ends at the tip disc")

    @property
    def count(self) -> int:
        return len(self.angles_deg)


@dataclasses.dataclass(frozen=True)
class Discs:
    """Spacer discs, evenly spaced, base not counted."""

    count: int = _f(_positive)
    outer_radius_m: float = _f(_positive)
    thickness_m: float = _f(_positive)
    lumped_mass_kg: float = _f(_nonnegative)


@dataclasses.dataclass(frozen=True)
class Environment:
    gravity_m_s2: float = _f(_nonnegative)


@dataclasses.dataclass(frozen=True)
class Rig:
    """Actuation and sensing rig (thesis §4)."""

    spool_radius_m: float = _f(_positive)
    gear_ratio: float = _f(_positive)
    encoder_counts_per_rev: int = _f(_positive)
    motor_voltage_v: float = _f(_positive)
    motor_torque_nm: float = _f(_positive)
    motor_speed_rpm: float = _f(_positive)
    motor_stall_torque_nm: float = _f(_positive)
    motor_no_load_speed_rpm: float = _f(_positive)
    motor_rotor_inertia_kgm2: float = _f(_nonnegative)
    control_rate_hz: float = _f(_positive)
    telemetry_rate_hz: float = _f(_positive)
    loadcell_rate_hz: float = _f(_positive)
    tracker_rate_hz: float = _f(_positive)
    tension_limit_n: float = _f(_positive)
    # The clamp's orientation (body → world) as a quaternion (w, x, y, z). Files written before
    # it existed get the thesis's horizontal clamp (thesis §8.3).
    base_quat: tuple[float, ...] = _f(_length(4), _nonzero_norm, default=HORIZONTAL_QUAT,
                                      source="default: the thesis's horizontal clamp (thesis §8.3)")

    @property
    def base_rotation(self) -> np.ndarray:
        """The clamp's orientation, 3×3 (body → world), from :attr:`base_quat`."""
        return rotation_of_quat(self.base_quat)

    @property
    def motor_stall_force_n(self) -> float:
        """A stalled motor's pull on its tendon at full supply, stall torque over spool radius (N)."""
        return self.motor_stall_torque_nm / self.spool_radius_m

    @property
    def motor_no_load_speed_m_per_s(self) -> float:
        """An unloaded motor's tendon speed at full supply, no-load speed times spool radius (m/s)."""
        return self.motor_no_load_speed_rpm * 2.0 * math.pi / 60.0 * self.spool_radius_m

    @property
    def motor_reflected_mass_kg(self) -> float:
        """The rotor's inertia seen at the tendon, J_rotor G² / r² (kg): 2.66 kg on the thesis rig."""
        return self.motor_rotor_inertia_kgm2 * self.gear_ratio**2 / self.spool_radius_m**2

    @property
    def tendon_m_per_count(self) -> float:
        """Tendon length per encoder count (m); 9.4e-7 m on the thesis rig."""
        return 2.0 * math.pi * self.spool_radius_m / (self.encoder_counts_per_rev * self.gear_ratio)


@dataclasses.dataclass(frozen=True)
class Sensors:
    """Load cells and tracker. The cells' rated sensitivity bounds the calibrations the board
    accepts (25 % either way) and their capacity bounds the tension limit."""

    loadcell_gain_counts_per_n: float = _f(_positive)
    loadcell_offset_counts: tuple[float, ...] = _f()
    loadcell_noise_n: float = _f(_nonnegative)
    tracker_noise_m: float = _f(_nonnegative)
    tracker_noise_rad: float = _f(_nonnegative)
    loadcell_capacity_n: float = _f(_positive, default=9.80665,
                                    source="default: assumption: 1 kg load cells, as sensors.loadcell_gain_counts_per_n assumes")


@functools.cache
def _effects_section(keys: tuple[Key, ...]) -> type:
    """The ``[effects]`` section's dataclass for the keys the registered effects declare."""
    fields = []
    for key in keys:
        checks = ((_nonnegative,) if key.nonnegative else ()) + ((_choice(*key.choices),) if key.choices else ()) \
            + ((_length(key.size),) if isinstance(key.size, int) else ())
        fields.append((key.name, float if key.size is None else tuple[float, ...], _f(*checks)))
    cls = dataclasses.make_dataclass("Effects", fields, frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = ("Effects real rigs have, all off by default: the keys the effect modules of "
                   ":mod:`twin.effects` declare.")
    return cls


if TYPE_CHECKING:
    class Effects:
        """The type checker's view of the section made at import: a field per registered key."""

        def __getattr__(self, name: str) -> Any: ...
else:
    # The [effects] section of the registered effects (twin.effects.EFFECTS).
    Effects = _effects_section(parameter_keys())


@dataclasses.dataclass(frozen=True)
class SimSettings:
    elements: int = _f(_positive)
    timestep_s: float = _f(_positive)
    damping_time_s: float = _f(_nonnegative)
    shear_joints: bool = _f()
    axial_joints: bool = _f()
    slide_stride: int = _f(_positive)
    twist_stride: int = _f(_positive)
    tendon_routing: str = _f(_choice("continuous", "discs"))


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """The predictor's integration: RK4 over ``max(steps, ⌈backbone.length_m / max_step_m⌉)``
    steps (:meth:`Params.predictor_steps`), so that a longer robot keeps the tip accuracy."""

    steps: int = _f(_positive)
    tolerance: float = _f(_positive)
    max_iterations: int = _f(_positive)
    max_step_m: float = _f(_positive, default=0.005,
                           source="default: chosen by measurement: the endoscope's 60 mm / 12 steps puts the tip within "
                                  "1.6e-7 m of 640 steps (twin bench predictor); 150 mm at 30 steps 3.6e-7 m")


def _sections() -> dict[str, type]:
    """Section name → its dataclass; ``[effects]`` as the effects registered now declare it."""
    return {
        "backbone": Backbone,
        "tendons": Tendons,
        "discs": Discs,
        "environment": Environment,
        "rig": Rig,
        "sensors": Sensors,
        "effects": _effects_section(parameter_keys()),
        "sim": SimSettings,
        "solver": SolverSettings,
    }


@dataclasses.dataclass(frozen=True)
class Params:
    """The frozen parameter set. ``sources`` maps ``"section.key"`` to where the value came from."""

    backbone: Backbone
    tendons: Tendons
    discs: Discs
    environment: Environment
    rig: Rig
    sensors: Sensors
    effects: Effects
    sim: SimSettings
    solver: SolverSettings
    sources: Mapping[str, str] = dataclasses.field(default_factory=dict, compare=False)

    def tendon_ends_m(self) -> tuple[float, ...]:
        """Arc length (m) where each tendon is anchored: its ``tendons.end_discs`` disc, else the tip."""
        b, t, d = self.backbone, self.tendons, self.discs
        ends = t.end_discs or (d.count,) * t.count
        return tuple(b.length_m * float(e) / d.count for e in ends)

    def predictor_steps(self) -> int:
        """RK4 steps of the predictor over the backbone: ``solver.steps``, or more where the
        backbone is longer than ``solver.steps · solver.max_step_m``."""
        return max(self.solver.steps, math.ceil(self.backbone.length_m / self.solver.max_step_m - 1e-9))

    def source(self, key: str) -> str:
        """Where the value of ``"section.key"`` came from (thesis / assumption / fitted / override)."""
        return self.sources[key]

    def get(self, key: str) -> Any:
        section, name = _split_key(key)
        return getattr(getattr(self, section), name)

    def replace(self, values: Mapping[str, Any], source: str = "override") -> "Params":
        """A new parameter set with ``{"section.key": value}`` replaced and validated."""
        raw = self.to_dict()
        for key, value in values.items():
            section, name = _split_key(key)
            raw[section][name] = {"value": value, "source": source}
        return _from_dict(raw, origin="replace()")

    def to_dict(self) -> dict[str, dict[str, dict[str, Any]]]:
        """``{section: {key: {"value": v, "source": s}}}``, as in the TOML file."""
        out: dict[str, dict[str, dict[str, Any]]] = {}
        for section in _sections():
            obj = getattr(self, section)
            out[section] = {
                f.name: {
                    "value": list(getattr(obj, f.name))
                    if isinstance(getattr(obj, f.name), tuple)
                    else getattr(obj, f.name),
                    "source": self.sources.get(f"{section}.{f.name}", ""),
                }
                for f in dataclasses.fields(obj)
            }
        return out

    def to_toml(self) -> str:
        """The parameter set as TOML, in the format of ``models/endoscope/endoscope.toml``."""
        lines = ["# twin parameter set, written by twin.params.Params.to_toml"]
        for section, entries in self.to_dict().items():
            lines.append(f"\n[{section}]")
            for key, entry in entries.items():
                lines.append(
                    f"{key} = {{ value = {_toml_value(entry['value'])}, "
                    f"source = {_toml_value(entry['source'])} }}"
                )
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(self.to_toml())
        return path


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if not isinstance(value, float) else _toml_float(value)
    if isinstance(value, str):
        # tomli-w escapes what a TOML basic string cannot hold (newlines, control characters);
        # escaping only quotes and backslashes wrote files that could not be read back.
        import tomli_w

        return tomli_w.dumps({"v": value}).removeprefix("v = ").rstrip("\n")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def _toml_float(x: float) -> str:
    text = repr(float(x))
    return text if ("." in text or "e" in text or "n" in text) else text + ".0"


def _split_key(key: str) -> tuple[str, str]:
    parts = key.split(".")
    sections = _sections()
    if len(parts) != 2 or parts[0] not in sections:
        raise ParameterError(
            f"unknown parameter key {key!r}: expected 'section.key' with section one of "
            f"{', '.join(sections)}"
        )
    names = [f.name for f in dataclasses.fields(sections[parts[0]])]
    if parts[1] not in names:
        raise ParameterError(f"unknown parameter key {key!r}: {parts[0]} has {', '.join(names)}")
    return parts[0], parts[1]


def _coerce(key: str, value: Any, annotation: Any) -> Any:
    """Convert a TOML value to the field's type, refusing what does not fit."""
    origin = typing.get_origin(annotation)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ParameterError(f"{key} = {value!r}: must be a list of numbers")
        return tuple(_coerce(key, v, float) for v in value)
    if annotation is bool:
        if not isinstance(value, bool):
            raise ParameterError(f"{key} = {value!r}: must be true or false")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ParameterError(f"{key} = {value!r}: must be a string")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                isinstance(value, float) and not value.is_integer()):
            raise ParameterError(f"{key} = {value!r}: must be a whole number")
        if abs(value) > _INT_MAX:
            raise ParameterError(f"{key} = {value!r}: must be a whole number within ±{_INT_MAX}")
        return int(value)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"{key} = {value!r}: must be a number")
        if not math.isfinite(value):
            raise ParameterError(f"{key} = {value!r}: must be finite")
        return float(value)
    raise TypeError(annotation)


def _effect_off(name: str, tendons: int):
    """The value of ``effects.<name>`` that leaves its effect off, sized for ``tendons`` tendons."""
    key = next(k for k in parameter_keys() if k.name == name)
    if key.size is None:
        return key.off
    return (key.off,) * (key.size if isinstance(key.size, int) else tendons)


def _from_dict(raw: Mapping[str, Any], origin: str) -> Params:
    """Validate a ``{section: {key: {"value", "source"}}}`` mapping into :class:`Params`.

    Raises:
        ParameterError: one message naming every key that is wrong, not only the first.
    """
    sections: dict[str, Any] = {}
    sources: dict[str, str] = {}
    had_segments = "segments" in raw
    raw, problems = _from_segments(raw, origin)
    section_types = _sections()
    unknown = set(raw) - set(section_types)
    if unknown:
        problems.append(f"{origin}: unknown section(s) {sorted(unknown)}")
    for section, cls in section_types.items():
        table = raw.get(section, {} if section == "effects" else None)
        if table is None:
            problems.append(f"{origin}: missing section [{section}]")
            continue
        if not isinstance(table, Mapping):
            problems.append(f"{origin}: [{section}] must be a table of keys, not {table!r}")
            continue
        hints = typing.get_type_hints(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        extra = set(table) - set(names)
        if extra:
            problems.append(f"{origin}: unknown key(s) {sorted(f'{section}.{k}' for k in extra)}")
        kwargs = {}
        for f in dataclasses.fields(cls):
            key = f"{section}.{f.name}"
            try:
                kwargs[f.name], sources[key] = _entry(origin, key, f, table, hints[f.name], sections)
            except ParameterError as exc:
                problems.append(str(exc))
        if len(kwargs) == len(names):
            sections[section] = cls(**kwargs)
    if had_segments:
        # Keys the segments set are missing only because the segments were wrong (said above).
        problems = [p for p in problems if not any(p.endswith(f"missing key {key}") for key in _SEGMENT_SET)]
    if not problems:
        params = Params(**sections, sources=sources)
        problems += _consistency_problems(params)
    if problems:
        raise ParameterError("; ".join(problems))
    return params


# What a [[segments]] entry holds, and what each of its tendons holds.
_SEGMENT_KEYS = ("length_m", "discs", "tendons", "source")
_SEGMENT_TENDON_KEYS = ("angle_deg", "radius_m", "routing", "source")
# The keys [[segments]] set: a file gives them one way or the other.
_SEGMENT_SET = ("backbone.length_m", "discs.count", "tendons.angles_deg", "tendons.end_discs")


def _from_segments(raw: Mapping[str, Any], origin: str) -> tuple[dict, list[str]]:
    """The file's ``[[segments]]`` (a robot described segment by segment, base first) turned into
    the arrays the model reads, and the problems found: ``backbone.length_m`` (their sum),
    ``discs.count`` (their sum), ``tendons.angles_deg`` (every segment's tendons, in order) and
    ``tendons.end_discs`` (each tendon anchored at its segment's last disc). The model has one
    tendon radius and routing and evenly spaced discs: segments that differ in them are refused.
    A file without ``[[segments]]`` is returned as it is."""
    raw = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in raw.items()}
    segments = raw.pop("segments", None)
    if segments is None:
        return raw, []
    where = f"{origin}: [[segments]]"
    if not isinstance(segments, list) or not segments or not all(isinstance(seg, Mapping) for seg in segments):
        return raw, [f"{where} must be one or more tables ([[segments]] with length_m, discs and tendons)"]
    problems: list[str] = []
    given_twice = [key for key in _SEGMENT_SET
                   if isinstance(raw.get(key.split(".")[0]), Mapping) and key.split(".")[1] in raw[key.split(".")[0]]]
    if given_twice:
        problems.append(f"{where} set {', '.join(given_twice)}: give them as segments or as keys, not both")

    def plain(entry):
        return (entry.get("value"), str(entry.get("source", ""))) if isinstance(entry, Mapping) else (entry, "")

    lengths: list[float] = []
    discs: list[int] = []
    angles: list[float] = []
    ends: list[Any] = []
    radii: set[float] = set()
    routings: set[str] = set()
    sources: list[str] = []
    for i, seg in enumerate(segments):
        at = f"segments[{i}]"
        unknown = sorted(set(seg) - set(_SEGMENT_KEYS))
        if unknown:
            problems.append(f"{at}: unknown key(s) {unknown}; a segment has {', '.join(_SEGMENT_KEYS)}")
        length, length_source = plain(seg.get("length_m"))
        count, count_source = plain(seg.get("discs"))
        if isinstance(length, bool) or not isinstance(length, (int, float)) or not math.isfinite(length) or length <= 0:
            problems.append(f"{at}.length_m = {length!r}: must be a number > 0")
            length = None
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            problems.append(f"{at}.discs = {count!r}: must be a whole number >= 1")
            count = None
        tendons = seg.get("tendons")
        if not isinstance(tendons, list) or not tendons or not all(isinstance(t, Mapping) for t in tendons):
            problems.append(f"{at}.tendons = {tendons!r}: must be a list of tables {{ angle_deg = ..., radius_m = ..., "
                            "routing = ... }}, one per tendon ending at this segment's last disc")
            tendons = []
        for j, tendon in enumerate(tendons):
            bad = sorted(set(tendon) - set(_SEGMENT_TENDON_KEYS))
            if bad:
                problems.append(f"{at}.tendons[{j}]: unknown key(s) {bad}; a tendon has {', '.join(_SEGMENT_TENDON_KEYS)}")
            angle = tendon.get("angle_deg")
            if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not math.isfinite(angle):
                problems.append(f"{at}.tendons[{j}].angle_deg = {angle!r}: must be a number")
                continue
            angles.append(float(angle))
            ends.append(None if count is None else sum(discs) + count)
            if "radius_m" in tendon:
                radii.add(tendon["radius_m"])
            if "routing" in tendon:
                routings.add(tendon["routing"])
        if length is not None and count is not None:
            if lengths and not math.isclose(length / count, lengths[0] / discs[0], rel_tol=1e-9):
                problems.append(f"{at}: {count} discs over {length!r} m are {length / count * 1e3:.4g} mm apart, "
                                f"segments[0]'s {lengths[0] / discs[0] * 1e3:.4g} mm: the model spaces the discs "
                                "evenly over the backbone")
            lengths.append(length)
            discs.append(count)
        sources.append(str(seg.get("source", "")) or length_source or count_source)
    for name, values in (("radius_m", radii), ("routing", routings)):
        existing = raw.get("tendons", {}).get(name) if isinstance(raw.get("tendons"), Mapping) else None
        if len(values) > 1:
            problems.append(f"{where}: tendons of radius_m / routing {sorted(map(str, values))}: the model has one "
                            f"tendons.{name} for every tendon")
        elif values and existing is not None and plain(existing)[0] not in values:
            problems.append(f"{where}: tendons' {name} {next(iter(values))!r} differs from tendons.{name} = "
                            f"{plain(existing)[0]!r}")
    if problems:
        return raw, problems
    source = "segments: " + "; ".join(f"[{i}] {s}" for i, s in enumerate(sources) if s) if any(sources) else "segments"
    single = len(segments) == 1
    settings: dict[str, dict[str, Any]] = {"backbone": {"length_m": sum(lengths)}, "discs": {"count": sum(discs)},
                "tendons": {"angles_deg": angles, "end_discs": [] if single else [float(e) for e in ends]}}
    if radii:
        settings["tendons"]["radius_m"] = next(iter(radii))
    if routings:
        settings["tendons"]["routing"] = next(iter(routings))
    for section, section_values in settings.items():
        table = raw.setdefault(section, {})
        if not isinstance(table, dict):
            continue  # the section's own problem, named when it is read
        for key, value in section_values.items():
            table[key] = {"value": value, "source": source}
    return raw, []


def _entry(origin: str, key: str, f: dataclasses.Field, table: Mapping, annotation, sections: dict):
    """(value, source) of one key of ``table``, checked; a key a file leaves out gets its default."""
    if f.name not in table:
        if key.startswith("effects."):
            # An effect a parameter file does not mention is off on that robot. Without a valid
            # [tendons] (already a problem, so nothing is built) it is sized for none.
            tendons = sections["tendons"].count if "tendons" in sections else 0
            return _effect_off(f.name, tendons), "default: off"
        if f.default is dataclasses.MISSING:
            raise ParameterError(f"{origin}: missing key {key}")
        return f.default, f.metadata["default_source"]
    entry = table[f.name]
    if isinstance(entry, Mapping):
        if "value" not in entry:
            raise ParameterError(f"{origin}: {key} has no 'value'")
        value, source = entry["value"], str(entry.get("source", ""))
    else:
        value, source = entry, ""
    value = _coerce(key, value, annotation)
    for check in f.metadata.get("checks", ()):
        problem = check(value)
        if problem:
            raise ParameterError(f"{key} = {value!r}: {problem}")
    return value, source


def _consistency_problems(p: Params) -> list[str]:
    """Checks that span keys: the geometry must fit together, lists must match the tendons."""
    problems = []
    t, b, d = p.tendons, p.backbone, p.discs
    for key, radius in (("tendons.radius_m", t.radius_m), ("tendons.tip_radius_m", t.tip_radius_m)):
        if radius + t.diameter_m / 2 > d.outer_radius_m:
            problems.append(f"{key} = {radius!r}: tendon lies outside the discs "
                            f"(discs.outer_radius_m = {d.outer_radius_m!r})")
    if d.outer_radius_m <= b.radius_m:
        problems.append(f"discs.outer_radius_m = {d.outer_radius_m!r}: must exceed backbone.radius_m = {b.radius_m!r}")
    if d.thickness_m * d.count >= b.length_m:
        problems.append(f"discs.thickness_m = {d.thickness_m!r}: {d.count} discs do not fit in "
                        f"backbone.length_m = {b.length_m!r}")
    n = t.count
    per_tendon = [k.key for k in parameter_keys() if k.size == PER_TENDON]
    for key in per_tendon + ["sensors.loadcell_offset_counts"]:
        if len(p.get(key)) != n:
            problems.append(f"{key} = {list(p.get(key))!r}: must have one entry per tendon ({n})")
    problems += _rig_problems(p)
    if p.sim.elements < d.count:
        problems.append(f"sim.elements = {p.sim.elements!r}: must be >= discs.count = {d.count}")
    if t.end_discs:
        if len(t.end_discs) != n:
            problems.append(f"tendons.end_discs = {list(t.end_discs)!r}: must have one entry per tendon ({n})")
        bad = [e for e in t.end_discs if not (float(e).is_integer() and 1 <= e <= d.count)]
        if bad:
            problems.append(f"tendons.end_discs = {list(t.end_discs)!r}: {bad} beyond the discs: each must be a "
                            f"disc number 1 … discs.count = {d.count} (the tip)")
    return problems


def _rig_problems(p: Params) -> list[str]:
    """The load cells, the tension limit and the motors must be ones the board can hold (firmware/PROTOCOL.md)."""
    problems = []
    limit, capacity, gain = p.rig.tension_limit_n, p.sensors.loadcell_capacity_n, p.sensors.loadcell_gain_counts_per_n
    if limit > min(capacity, MAX_TENSION_LIMIT_N):
        problems.append(f"rig.tension_limit_n = {limit!r}: must be <= sensors.loadcell_capacity_n = {capacity!r} "
                        f"and <= {MAX_TENSION_LIMIT_N:g} N, the most the firmware accepts")
    low, high = RATED_GAIN_COUNTS_PER_N
    if not low <= gain <= high:
        problems.append(f"sensors.loadcell_gain_counts_per_n = {gain!r}: must be in {low:g}..{high:.0f} counts/N "
                        "(the HX711's 24-bit range holds the largest limit; a count is at most 10 mN)")
    rig = p.rig
    motors = {"stall_force_n": rig.motor_stall_force_n, "no_load_speed_m_per_s": rig.motor_no_load_speed_m_per_s,
              "reflected_mass_kg": rig.motor_reflected_mass_kg}
    problems += [f"the motors' {line} (from rig.motor_stall_torque_nm, rig.motor_no_load_speed_rpm, "
                 "rig.motor_rotor_inertia_kgm2, rig.gear_ratio, rig.spool_radius_m)" for line in motor_problems(motors)]
    return problems


def parse_override(text: str) -> tuple[str, Any]:
    """Parse ``section.key=value``; the value is read as TOML, a bare word as a string."""
    if "=" not in text:
        raise ParameterError(f"--set {text!r}: expected section.key=value")
    key, _, value_text = text.partition("=")
    key, value_text = key.strip(), value_text.strip()
    _split_key(key)
    try:
        value = tomllib.loads(f"v = {value_text}")["v"]
    except tomllib.TOMLDecodeError:
        if value_text and all(c.isalnum() or c in "_-" for c in value_text) and value_text.lower() != "nan":
            value = value_text
        else:
            raise ParameterError(f"--set {text!r}: {value_text!r} is not a TOML value") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ParameterError(f"{key} = {value!r}: must be finite")
    return key, value


def load_params(
    path: str | Path | None = None,
    overrides: Iterable[str] | Mapping[str, Any] = (),
) -> Params:
    """Load and validate a parameter file, then apply overrides.

    Args:
        path: a TOML file in the format of ``models/endoscope/endoscope.toml``; default that file.
        overrides: ``["section.key=value", ...]`` strings (as from ``--set``) or a mapping.

    Raises:
        ParameterError: the file is not a TOML parameter file, or a value is missing, unknown or
            invalid (the message names the file, the key and the value).
        OSError: ``path`` cannot be read (FileNotFoundError when it does not exist).
    """
    from twin.inputs import PARAMS_MAX_BYTES, InputFileError, read_input

    path = Path(path) if path is not None else DEFAULT_PARAMS_PATH
    try:
        raw = tomllib.loads(read_input(path, max_bytes=PARAMS_MAX_BYTES).decode("utf-8"))
    except InputFileError as exc:
        raise ParameterError(f"{exc}; a TOML parameter file was expected") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"{path}: not a TOML parameter file (not valid TOML: {exc})") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{path}: not a TOML parameter file (byte {exc.start + 1} is not UTF-8 text; "
                             "is it a binary file?)") from None
    try:
        params = _from_dict(raw, origin=str(path))
    except ParameterError as exc:
        text = str(exc)
        raise ParameterError(text if text.startswith(f"{path}:") else f"{path}: {text}") from None
    if isinstance(overrides, Mapping):
        values = dict(overrides)
    else:
        values = dict(parse_override(o) for o in overrides)
    return params.replace(values) if values else params
