"""Whether ``twin discrepancy --device`` runs its deciding experiments to the end under hidden
tendon friction, on the robots of the zoo.

For each robot, friction coefficient μ and seed: a quick sweep of the twin with μ hidden
(``twin validate --quick --twin-set effects.tendon_friction_coeff=μ --seed S``), then
``twin discrepancy DATASET --device sim://?seed=S --twin-set ...`` twice: on the dataset as
recorded, and on a copy without its sliding-state columns (``slide_*``, as a host that does not
record them writes it), which leaves friction tied with static effects and so makes the deciding
experiments run. Each answer's exit code, verdict and the experiments it ran are printed; an
experiment that stopped is named with its one line, and the dataset must then be byte for byte
what it was.

Usage: python scripts/deciding_experiments.py [--robots A,B,...] [--mu 0.3,0.6] [--seeds 0,1] [--out DIR]
  defaults: every robot of models/, μ 0.3 and 0.6, seed 0, DIR a temporary folder.
Exits 1 when a deciding experiment stopped, or changed a dataset it stopped in.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import shutil
import sys
import tempfile
from pathlib import Path

from twin.cli import main as twin

ROBOTS = ("endoscope", "endoscope-soft-g", "helical", "long", "stiff-long", "three-tendon", "two-segment")


def _without_sliding_states(folder: Path) -> None:
    path = folder / "measurements.csv"
    rows = list(csv.reader(open(path, newline="")))
    keep = [i for i, name in enumerate(rows[0]) if not name.startswith("slide_")]
    with open(path, "w", newline="") as f:
        csv.writer(f, lineterminator="\r\n").writerows([[r[i] for i in keep] for r in rows])


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = twin(list(argv))
    return code, out.getvalue(), err.getvalue()


def _case(robot: str, mu: float, seed: int, root: Path) -> list[dict]:
    hidden = f"effects.tendon_friction_coeff={mu:g}"
    code, _, err = _run("validate", "--robot", robot, "--quick", "--seed", str(seed), "--twin-set", hidden,
                        "--out", str(root / "runs"))
    runs = sorted((root / "runs").glob("validate-*"))
    if code != 0 or not runs:
        return [{"slide": "-", "exit": code, "verdict": "sweep failed", "ran": err.strip().splitlines()[-1:]}]
    recorded = runs[-1] / "dataset"
    out = []
    for slide in ("kept", "removed"):
        data = root / f"dataset-{slide}"
        shutil.copytree(recorded, data)
        if slide == "removed":
            _without_sliding_states(data)
        before = {p.name: p.read_bytes() for p in data.iterdir() if p.is_file()}
        code, stdout, err = _run("discrepancy", str(data), "--device", f"sim://?seed={seed}", "--twin-set", hidden,
                                 "--json")
        row = {"slide": slide, "exit": code}
        if stdout.strip():
            result = json.loads(stdout)
            row["verdict"] = result["verdict"]
            row["ran"] = (result.get("decided_by") or {}).get("experiments", [])
        else:
            row["verdict"] = "-"
            row["ran"] = [line for line in err.splitlines() if line.startswith("twin discrepancy")][-1:]
            row["dataset"] = ("unchanged" if {p.name: p.read_bytes() for p in data.iterdir() if p.is_file()} == before
                              else "CHANGED")
        out.append(row)
        shutil.rmtree(data)
    shutil.rmtree(root / "runs")
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default=",".join(ROBOTS))
    parser.add_argument("--mu", default="0.3,0.6")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    failed = 0
    with tempfile.TemporaryDirectory(dir=args.out) as scratch:
        for robot in args.robots.split(","):
            for mu in (float(m) for m in args.mu.split(",")):
                for seed in (int(s) for s in args.seeds.split(",")):
                    for row in _case(robot, mu, seed, Path(scratch)):
                        print(f"{robot:16s} mu {mu:<4g} seed {seed}  slide_* {row['slide']:7s}  exit {row['exit']}  "
                              f"{row['verdict']:11s}  {'; '.join(row['ran']) or 'nothing run'}"
                              + (f"  (dataset {row['dataset']})" if "dataset" in row else ""), flush=True)
                        failed += row["exit"] not in (0, 3) or row.get("dataset") == "CHANGED"
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
