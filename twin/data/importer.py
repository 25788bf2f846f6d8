"""``twin import``: a lab's own measurements (a CSV of its layout) into a dataset the twin reads.

A map file (TOML) says which CSV columns hold which quantities and in which units; the result is
a ``twin-dataset`` version 2 (``docs/dataset.md``) of the robot given (``--robot`` or
``--params``), so ``twin discrepancy`` and its report read it like a run of ``twin validate``.
Worked example and the map's keys: ``docs/import.md``.

Quantities (tables of the map file):

============  ========  ========================================  ===========================
table         needed    keys                                      units
============  ========  ========================================  ===========================
``tip``       yes       ``columns`` (x, y, z), ``unit``,          m, cm, mm, um
                        ``origin`` (the base centre in the
                        CSV's frame, same unit; default 0)
``tension``   yes       ``columns`` (one per tendon), ``unit``    N, mN, kg, g (a hanging
                                                                  weight), counts (raw load
                                                                  cell: the robot's
                                                                  ``sensors.loadcell_*``)
``tip_mass``  yes       ``column`` or ``value``, ``unit``         kg, g
``length``    no        ``columns`` (one per tendon), ``unit``    m, mm, um, counts (encoder:
                                                                  the robot's spool and gear)
``command``   no        ``kappa``, ``kappa_unit``, ``phi``,        1/m, 1/mm; deg, rad
                        ``phi_unit`` (columns)
``config``    no        ``column`` (rows of one number are        —
                        repeats of one pose)
``repeat``    no        ``column``                                —
``orientation`` no      ``columns`` (w, x, y, z)                  —
``time``      no        ``column``, ``unit``                      s, ms
============  ========  ========================================  ===========================

and ``[csv]``: ``delimiter`` (default ``,``), ``experiment`` (default ``imported``), ``notes``.
Without ``command`` every row is a free pose (its κ and φ empty); without ``config`` rows are
numbered 1, 2, … in file order. Every refusal is one line naming the map key, the CSV column or
row, and the value.
"""

from __future__ import annotations

import argparse
import csv
import math
import shutil
import tomllib
from pathlib import Path

import numpy as np

__all__ = ["MapError", "import_csv", "register"]

# Units per kind of quantity: name → factor to SI (None: converted through the robot).
_UNITS: dict[str, dict[str, float | None]] = {
    "position": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6},
    "length": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "counts": None},
    "tension": {"N": 1.0, "mN": 1e-3, "kg": None, "g": None, "counts": None},
    "mass": {"kg": 1.0, "g": 1e-3},
    "curvature": {"1/m": 1.0, "1/mm": 1e3},
    "angle": {"deg": 1.0, "rad": 180.0 / math.pi},
    "time": {"s": 1.0, "ms": 1e-3},
}
_TABLES = {"csv": {"delimiter", "experiment", "notes"}, "tip": {"columns", "unit", "origin"},
           "tension": {"columns", "unit"}, "tip_mass": {"column", "value", "unit"}, "length": {"columns", "unit"},
           "command": {"kappa", "kappa_unit", "phi", "phi_unit"}, "config": {"column"}, "repeat": {"column"},
           "orientation": {"columns"}, "time": {"column", "unit"}}
_REQUIRED = ("tip", "tension", "tip_mass")


class MapError(ValueError):
    """The CSV or its map cannot be imported (the message names the key, column or row and value)."""


def _table(mapping: dict, name: str, path: Path) -> dict | None:
    table = mapping.get(name)
    if table is None:
        return None
    if not isinstance(table, dict):
        raise MapError(f"{path}: [{name}] must be a table")
    unknown = sorted(set(table) - _TABLES[name])
    if unknown:
        raise MapError(f"{path}: [{name}] has unknown key(s) {', '.join(unknown)}; it takes "
                           f"{', '.join(sorted(_TABLES[name]))}")
    return table


def _unit(path: Path, where: str, unit, kind: str) -> tuple[str, float | None]:
    units = _UNITS[kind]
    if unit not in units:
        raise MapError(f"{path}: {where} = {unit!r}: unknown unit; use one of {', '.join(units)}")
    return unit, units[unit]


def _columns(path: Path, where: str, names, count: int | None) -> list[str]:
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or \
            (count is not None and len(names) != count):
        need = f"{count} column names" if count is not None else "a list of column names"
        raise MapError(f"{path}: {where} = {names!r}: expected {need}")
    return names


def read_map(path: str | Path, tendons: int) -> dict:
    """The map file, checked: every table and key known, every unit known, every required
    quantity there, the per-tendon lists of ``tendons`` columns.

    Raises:
        MapError: the first problem, in one line naming the key and value.
    """
    path = Path(path)
    try:
        mapping = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise MapError(f"{path}: not TOML: {exc}") from None
    unknown = sorted(set(mapping) - set(_TABLES))
    if unknown:
        raise MapError(f"{path}: unknown table(s) {', '.join(unknown)}; a map has {', '.join(_TABLES)}")
    missing = [name for name in _REQUIRED if name not in mapping]
    if missing:
        raise MapError(f"{path}: no [{missing[0]}]: the {missing[0].replace('_', ' ')} is required "
                           f"(required: {', '.join(_REQUIRED)})")
    tables = {name: _table(mapping, name, path) for name in _TABLES}
    # The required tables are there (checked above): a missing one is the only None.
    tip, tension, mass = (tables[name] or {} for name in _REQUIRED)
    out: dict = {"csv": tables["csv"] or {}}
    out["tip"] = (_columns(path, "tip.columns", tip.get("columns"), 3),
                  _unit(path, "tip.unit", tip.get("unit"), "position")[1],
                  np.asarray(tip.get("origin", [0.0, 0.0, 0.0]), dtype=float))
    if out["tip"][2].shape != (3,):
        raise MapError(f"{path}: tip.origin = {tip.get('origin')!r}: expected 3 numbers")
    out["tension"] = (_columns(path, "tension.columns", tension.get("columns"), tendons),
                      _unit(path, "tension.unit", tension.get("unit"), "tension")[0])
    if ("column" in mass) == ("value" in mass):
        raise MapError(f"{path}: [tip_mass] needs a column or a value (one of them)")
    out["tip_mass"] = (mass.get("column"), mass.get("value"), _unit(path, "tip_mass.unit", mass.get("unit"), "mass")[1])
    if tables["length"] is not None:
        length = tables["length"]
        out["length"] = (_columns(path, "length.columns", length.get("columns"), tendons),
                         _unit(path, "length.unit", length.get("unit"), "length")[0])
    if tables["command"] is not None:
        command = tables["command"]
        for key in ("kappa", "phi"):
            if not isinstance(command.get(key), str):
                raise MapError(f"{path}: command.{key} = {command.get(key)!r}: expected a column name "
                                   "(leave [command] out for free poses)")
        out["command"] = (command["kappa"], _unit(path, "command.kappa_unit", command.get("kappa_unit"), "curvature")[1],
                          command["phi"], _unit(path, "command.phi_unit", command.get("phi_unit"), "angle")[1])
    for name in ("config", "repeat"):
        table = tables[name]
        if table is not None:
            out[name] = _columns(path, f"{name}.column", [table.get("column")], 1)[0]
    if tables["orientation"] is not None:
        out["orientation"] = _columns(path, "orientation.columns", tables["orientation"].get("columns"), 4)
    if tables["time"] is not None:
        out["time"] = (_columns(path, "time.column", [tables["time"].get("column")], 1)[0],
                       _unit(path, "time.unit", tables["time"].get("unit", "s"), "time")[1])
    return out


def _tensions_n(values: np.ndarray, unit: str, params) -> np.ndarray:
    if unit in ("N", "mN"):
        return values * _UNITS["tension"][unit]
    if unit in ("kg", "g"):  # a weight hung on the line: its force under the robot's g
        return values * (1.0 if unit == "kg" else 1e-3) * params.environment.gravity_m_s2
    s = params.sensors  # raw load-cell counts through the robot's nominal calibration
    return (values - np.asarray(s.loadcell_offset_counts, dtype=float)) / s.loadcell_gain_counts_per_n


def _lengths_m(values: np.ndarray, unit: str, params) -> np.ndarray:
    if unit == "counts":
        return values * params.rig.tendon_m_per_count
    return values * _UNITS["length"][unit]


def import_csv(csv_path: str | Path, map_path: str | Path, out: str | Path, params, *, robot: str | None = None,
               base_rotation=None):
    """Import ``csv_path`` with the map ``map_path`` into a dataset at ``out`` for the robot of ``params``.

    Args:
        base_rotation: the base pose the data were taken in (3×3, body → world); default the
            parameter set's ``rig.base_quat``.

    Returns:
        The :class:`twin.data.dataset.Dataset` written.

    Raises:
        MapError: the map or the CSV is wrong (a missing quantity or column, an unknown
            unit, a cell that is not a number), in one line; nothing is written then.
        DatasetError: a value the dataset refuses (a tension below its floor).
    """
    from twin.data.dataset import DatasetWriter, read_dataset

    csv_path, out = Path(csv_path), Path(out)
    n = params.tendons.count
    spec = read_map(map_path, n)
    delimiter = spec["csv"].get("delimiter", ",")
    with csv_path.open(newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle, delimiter=delimiter)
        header = [h.strip() for h in next(reader, [])]
        table = [row for row in reader if any(cell.strip() for cell in row)]
    if not table:
        raise MapError(f"{csv_path}: no rows of data")
    index = {name: i for i, name in enumerate(header)}

    def column(name: str, where: str, *, numeric: bool = True) -> np.ndarray:
        if name not in index:
            raise MapError(f"{map_path}: {where} = {name!r}: no such column in {csv_path} (it has "
                               f"{', '.join(header)})")
        cells = []
        for r, row in enumerate(table, start=2):
            text = row[index[name]].strip() if index[name] < len(row) else ""
            try:
                value = float(text)
            except ValueError:
                raise MapError(f"{csv_path}: row {r}, column {name!r}: {text!r} is not a number") from None
            if not math.isfinite(value):
                raise MapError(f"{csv_path}: row {r}, column {name!r}: {text!r} is not finite")
            cells.append(value)
        return np.array(cells)

    names, scale, origin = spec["tip"]
    tip = (np.stack([column(c, "tip.columns", ) for c in names], axis=1) - origin) * scale
    names, unit = spec["tension"]
    tensions = _tensions_n(np.stack([column(c, "tension.columns") for c in names], axis=1), unit, params)
    mass_column, mass_value, mass_scale = spec["tip_mass"]
    mass = (column(mass_column, "tip_mass.column") if mass_column else np.full(len(table), float(mass_value))) * mass_scale
    rows = len(table)
    lengths = None
    if "length" in spec:
        names, unit = spec["length"]
        lengths = _lengths_m(np.stack([column(c, "length.columns") for c in names], axis=1), unit, params)
    kappa = phi = np.full(rows, np.nan)
    if "command" in spec:
        kappa_name, kappa_scale, phi_name, phi_scale = spec["command"]
        kappa = column(kappa_name, "command.kappa") * kappa_scale
        phi = column(phi_name, "command.phi") * phi_scale % 360.0
    config = column(spec["config"], "config.column") if "config" in spec else np.arange(1, rows + 1)
    repeat = column(spec["repeat"], "repeat.column") if "repeat" in spec else np.zeros(rows)
    for name, values in (("config", config), ("repeat", repeat)):
        if not np.all(values == np.round(values)):
            bad = int(np.flatnonzero(values != np.round(values))[0])
            raise MapError(f"{csv_path}: row {bad + 2}, {name} = {values[bad]!r}: not a whole number")
    quats = np.stack([column(c, "orientation.columns") for c in spec["orientation"]], axis=1) \
        if "orientation" in spec else None
    times = column(spec["time"][0], "time.column") * spec["time"][1] if "time" in spec else None
    if base_rotation is None:
        base_rotation = params.rig.base_rotation
    records = []
    for i in range(rows):
        row = {"config": int(config[i]), "repeat": int(repeat[i]), "kappa_cmd_per_m": float(kappa[i]),
               "phi_cmd_deg": float(phi[i]), "tip_mass_kg": float(mass[i]),
               "tip_x_m": tip[i, 0], "tip_y_m": tip[i, 1], "tip_z_m": tip[i, 2]}
        for k in range(n):
            row[f"tension_{k + 1}_n"] = float(tensions[i, k])
            if lengths is not None:
                row[f"length_{k + 1}_m"] = float(lengths[i, k])
        if quats is not None:
            row.update(zip(("tip_qw", "tip_qx", "tip_qy", "tip_qz"), (quats[i] / np.linalg.norm(quats[i])).tolist()))
        if times is not None:
            row["time_s"] = float(times[i])
        records.append(row)
    options = spec["csv"]
    notes = options.get("notes", f"imported by twin import from {csv_path.name} with the map {Path(map_path).name}")
    try:
        with DatasetWriter(out, experiment=str(options.get("experiment", "imported")),
                           device=f"imported from {csv_path.name}", params=params, base_rotation=base_rotation,
                           robot=robot, notes=str(notes), sync=False) as writer:
            for row in records:
                writer.write(row)
    except BaseException:
        # Nothing half-imported stays behind: a second try starts from an empty folder.
        shutil.rmtree(out, ignore_errors=True)
        raise
    return read_dataset(out)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``twin import`` to the ``twin`` command's subparsers."""
    from twin.cliargs import add_param_args, add_pose_args

    p = sub.add_parser("import", help="turn a lab's CSV (its own columns, units, free poses) into a dataset that "
                                      "twin discrepancy reads (docs/import.md)")
    p.add_argument("csv", metavar="CSV", help="the lab's measurements, one row per static pose, a header row")
    p.add_argument("--map", required=True, metavar="FILE",
                   help="TOML map: which columns hold which quantities, in which units (docs/import.md)")
    p.add_argument("--out", required=True, metavar="DIR", help="dataset folder to write (must not exist)")
    add_pose_args(p)
    add_param_args(p)
    p.set_defaults(func=run_import)


def run_import(args: argparse.Namespace) -> int:
    from twin.cliargs import UsageError, params_from_args, robot_name

    out = Path(args.out)
    if out.exists():
        raise UsageError(f"--out {args.out}: already exists; import writes a new dataset folder")
    for name in ("csv", "map"):
        if not Path(getattr(args, name)).is_file():
            raise UsageError(f"{'--map ' if name == 'map' else ''}{getattr(args, name)}: no such file")
    params = params_from_args(args)
    try:
        dataset = import_csv(args.csv, args.map, out, params, robot=robot_name(args))
    except MapError as exc:
        raise UsageError(str(exc)) from None
    free = int(np.count_nonzero(dataset.free))
    lengths = "with" if np.isfinite(dataset.lengths_m).all() else "without"
    print(f"twin import: {len(dataset)} rows ({free} free poses), {dataset.tendons} tendons, {lengths} tendon "
          f"lengths -> {out}; next: twin discrepancy {out}")
    return 0
