"""Fault injection on the measurement dataset and the experiment commands: torn rows, full disks,
non-finite values, resumes under other conditions, colliding run folders and ``--link`` onto a
file. Each attack must end in a readable dataset and one clear message, never a traceback."""

import datetime
import errno
import json
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import pytest

from twin import load_params
from twin import cliargs
from twin.cli import build_parser, main
from twin.data import dataset as dataset_module
from twin.data.dataset import DatasetError, DatasetWarning, DatasetWriter, read_dataset
from twin.experiments import commands
from twin.experiments.protocols import nominal_calibration
from twin.pose import HORIZONTAL

QUICK_CONFIGS = 24


def row(config, **extra):
    r = {"config": config, "kappa_cmd_per_m": 4.5, "phi_cmd_deg": 30.0, "tip_mass_kg": 0.005,
         "tip_x_m": 0.05 + config * 1e-3, "tip_y_m": 0.001, "tip_z_m": -0.01}
    for i in range(1, 5):
        r[f"tension_{i}_n"] = 1.2 + 0.1 * i
        r[f"length_{i}_m"] = -1e-4 * i
    r.update(extra)
    return r


def writer(folder, experiment="validation", params=None, device="sim://"):
    return DatasetWriter(folder, experiment=experiment, device=device, params=params or load_params(),
                         base_rotation=HORIZONTAL)


def written(folder, configs):
    with writer(folder) as w:
        for c in configs:
            w.write(row(c))
    return Path(folder) / "measurements.csv"


class FullDisk:
    """``os`` as :mod:`twin.data.dataset` sees it, on a disk that fills up after ``rows`` more rows:
    the next write puts half its bytes down, then fails with ENOSPC, as a real full disk does."""

    def __init__(self, rows: int):
        self.rows = rows

    def __getattr__(self, name):
        return getattr(os, name)

    def write(self, fd, data):
        if self.rows == 0:
            os.write(fd, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.rows -= 1
        return os.write(fd, data)


@pytest.fixture
def tiny_fs(tmp_path):
    """A 1 MiB tmpfs (root and a kernel that allows mounting it); :func:`fill` fills it up."""
    point = tmp_path / "tiny"
    point.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("a real full disk needs root to mount a tiny tmpfs")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(point)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"mounting a tiny tmpfs is not permitted here: {done.stderr.strip()}")
    try:
        yield point
    finally:
        subprocess.run(["umount", "-l", str(point)], capture_output=True)


def fill(folder: Path, leave_blocks: int = 0) -> None:
    """Fill the filesystem of ``folder`` but for ``leave_blocks`` 4 KiB blocks."""
    with open(folder / "filler", "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
        fh.truncate(max(0, fh.tell() - leave_blocks * 4096))


# --- torn rows -------------------------------------------------------------------------------


@pytest.mark.parametrize("tear", [
    lambda line: line[:40],                    # cut mid-row: too few fields
    lambda line: line[: line.rfind(b",") + 3],  # cut inside the last number: it would parse, wrongly
    lambda line: line + b"\r",                  # all but the last byte of the line end
    lambda line: b"\0" * 200,                   # the zeros a crash can leave at the end of a file
])
def test_a_torn_last_row_is_dropped_with_a_warning_naming_file_and_row(tmp_path, tear):
    path = written(tmp_path, [0, 1, 2])
    lines = path.read_bytes().split(b"\r\n")[:-1]
    path.write_bytes(b"\r\n".join(lines[:-1]) + b"\r\n" + tear(lines[-1]))
    with pytest.warns(DatasetWarning, match=rf"{path}: row 4 is incomplete"):
        d = read_dataset(tmp_path)
    assert list(d["config"]) == [0, 1]
    assert d["tip_x_m"][1] == row(1)["tip_x_m"]


def test_resuming_after_a_torn_row_cuts_it_off_and_appends_whole_rows(tmp_path):
    path = written(tmp_path, [0, 1, 2])
    whole = path.read_bytes()
    path.write_bytes(whole[:-30])
    with pytest.warns(DatasetWarning, match="row 4 is incomplete"):
        w = writer(tmp_path)
    with w:
        assert w.completed() == {0, 1}
        w.write(row(2))
        w.write(row(3))
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        d = read_dataset(tmp_path)
    assert list(d["config"]) == [0, 1, 2, 3]
    assert path.read_bytes().startswith(whole)


@pytest.mark.parametrize("damage, message", [
    (lambda line: line.replace(b"1.3", b"1.x", 1), r"row 3, column 'tension_1_n': '1.x' is not a number"),
    # The header: every column of a four-tendon dataset, the optional groups' too.
    (lambda line: line[:40], rf"row 3 has \d fields, the header {len(dataset_module.COLUMNS)}"),
])
def test_a_torn_row_in_the_middle_is_an_error_naming_file_row_and_column(tmp_path, damage, message):
    path = written(tmp_path, [0, 1, 2])
    lines = path.read_bytes().split(b"\r\n")
    lines[2] = damage(lines[2])
    path.write_bytes(b"\r\n".join(lines))
    for attempt in (lambda: read_dataset(tmp_path), lambda: writer(tmp_path)):
        with pytest.raises(DatasetError, match=rf"{path}: {message}"):
            attempt()


# --- values the reader would refuse ------------------------------------------------------------


@pytest.mark.parametrize("column, value, problem", [
    ("tip_x_m", math.nan, "is not a number"),
    ("tension_2_n", math.inf, "is not finite"),
    ("length_1_m", -math.inf, "is not finite"),
    ("tip_mass_kg", None, "is not a number"),
    ("tip_qw", math.inf, "is not finite"),
    ("config", 2.5, "is not a whole number"),
    ("tip_y_m", "0.1", "is not a number"),
    ("experiment", "a\nb", "holds a line break"),
])
def test_values_the_reader_would_refuse_are_refused_at_write_time(tmp_path, column, value, problem):
    path = written(tmp_path, [0])
    before = path.read_bytes()
    with writer(tmp_path) as w:
        with pytest.raises(ValueError, match=re.escape(f"column '{column}' = {value!r} {problem}")):
            w.write({**row(1), column: value})
    assert path.read_bytes() == before
    assert list(read_dataset(tmp_path)["config"]) == [0]


def test_a_command_with_half_of_its_bend_is_refused_a_free_pose_has_neither(tmp_path):
    path = written(tmp_path, [0])
    with writer(tmp_path) as w:
        with pytest.raises(ValueError, match=r"row for config 1 has a command κ or φ without the other"):
            w.write({**row(1), "kappa_cmd_per_m": None})
        w.write({**row(2), "kappa_cmd_per_m": None, "phi_cmd_deg": math.nan})
    d = read_dataset(tmp_path)
    assert d.free.tolist() == [False, True]
    # A torn edit by hand (one of the two cells emptied) is refused on reading, naming the row.
    text = path.read_text().replace(",4.5,30.0,", ",,30.0,", 1)
    path.write_text(text)
    with pytest.raises(ValueError, match=r"row 2 has a command κ or φ without the other"):
        read_dataset(tmp_path)


def test_an_unmeasured_optional_column_is_still_written_empty(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0, tip_qw=math.nan, time_s=None))
    assert math.isnan(read_dataset(tmp_path)["tip_qw"][0])


# --- failing writes ----------------------------------------------------------------------------


def test_a_write_that_fails_half_way_leaves_the_file_as_before_and_names_it(tmp_path, monkeypatch):
    path = written(tmp_path, [0, 1])
    before = path.read_bytes()
    disk = FullDisk(rows=0)
    monkeypatch.setattr(dataset_module, "os", disk)
    with writer(tmp_path) as w:
        with pytest.raises(OSError) as info:
            w.write(row(2))
        assert info.value.errno == errno.ENOSPC and info.value.filename == str(path)
        assert "config 2" in str(info.value)
        assert path.read_bytes() == before
        disk.rows = 1  # space again: the same writer carries on
        w.write(row(2))
    assert list(read_dataset(tmp_path)["config"]) == [0, 1, 2]


def test_a_real_full_disk_keeps_every_complete_row(tiny_fs):
    folder = tiny_fs / "dataset"
    with writer(folder) as w:
        fill(tiny_fs)
        rows = 0
        with pytest.raises(OSError) as info:
            for c in range(1000):
                w.write(row(c))
                rows += 1
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(folder / "measurements.csv")
    assert rows > 0  # the header's block had room for some rows
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        assert list(read_dataset(folder)["config"]) == list(range(rows))


def test_a_dataset_that_cannot_be_created_leaves_no_half_made_files(tiny_fs):
    fill(tiny_fs)
    folder = tiny_fs / "dataset"
    with pytest.raises(OSError) as info:
        writer(folder)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(folder / "metadata.json")
    assert list(folder.iterdir()) == []


def test_two_writers_on_one_dataset_are_refused(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
        with pytest.raises(DatasetError, match="another run is writing"):
            writer(tmp_path)


# --- the validate command under a full disk ---------------------------------------------------


def _stopped_cleanly(code, err):
    assert code == 4
    assert "Traceback" not in err
    assert "No space left on device" in err and "measurements.csv" in err
    command = [line.strip() for line in err.splitlines() if line.strip().startswith("twin validate --resume")]
    assert len(command) == 1, err
    return shlex.split(command[0])


def test_validate_stops_cleanly_on_a_full_disk_and_the_printed_command_resumes(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(dataset_module, "os", FullDisk(rows=3))
    code = main(["validate", "--quick", "--out", str(tmp_path), "--seed", "2"])
    resume = _stopped_cleanly(code, capsys.readouterr().err)
    folder = Path(resume[resume.index("--resume") + 1])
    assert list(read_dataset(folder)["config"]) == [0, 2, 9]
    assert (folder / "dataset" / "measurements.csv").read_bytes().endswith(b"\r\n")

    monkeypatch.setattr(dataset_module, "os", os)
    assert main(resume[1:]) == 0
    d = read_dataset(folder)
    assert len(d) == QUICK_CONFIGS and len(set(d["config"])) == QUICK_CONFIGS
    assert (folder / "report.md").exists()


def test_validate_on_a_real_full_disk_stops_cleanly_with_the_dataset_readable(tiny_fs):
    # Room for run.json, metadata.json and the header's block only: that block takes ~11 rows of
    # the 24, then the disk is full.
    params = load_params()
    metadata = json.dumps(dataset_module._metadata(experiment="validation", device="sim://", params=params,
                                                   base_rotation=HORIZONTAL, calibration=nominal_calibration(params)),
                          indent=1)
    fill(tiny_fs, leave_blocks=1 + math.ceil(len(metadata) / 4096) + 1)
    done = subprocess.run([sys.executable, "-m", "twin.cli", "validate", "--quick", "--out", str(tiny_fs)],
                          capture_output=True, text=True, timeout=300)
    resume = _stopped_cleanly(done.returncode, done.stderr)
    folder = Path(resume[resume.index("--resume") + 1])
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetWarning)
        rows = len(read_dataset(folder))
    assert 0 < rows < QUICK_CONFIGS


# --- resuming under other conditions ---------------------------------------------------------


@pytest.fixture
def stopped_run(tmp_path):
    """A ``twin validate --quick --seed 0`` run folder with two rows, as an interrupted run leaves it."""
    args = build_parser().parse_args(["validate", "--quick", "--seed", "0", "--out", str(tmp_path / "runs")])
    folder = commands._start_run(args, "validate")
    written(folder / "dataset", [0, 2])
    return folder


@pytest.mark.parametrize("options, difference", [
    (["--quick", "--seed", "3"], "--seed 3 here, 0 in the run"),
    (["--quick"], "--seed none here, 0 in the run"),
    (["--quick", "--seed", "0", "--set", "backbone.youngs_modulus_pa=9e6"],
     "backbone.youngs_modulus_pa 9000000.0 here, 8241400.0 in the run"),
    (["--quick", "--seed", "0", "--device", "sim://?pose=horizontal"],
     "--device sim://?pose=horizontal here, sim:// in the run"),
    (["--quick", "--seed", "0", "--twin-set", "effects.tension_gain_error=[0.05,0,0,0]"],
     "--twin-set effects.tension_gain_error=[0.05, 0, 0, 0] here, none in the run"),
    (["--seed", "0"], "--quick off here, on in the run"),
])
def test_resume_under_other_conditions_is_refused_naming_the_difference(stopped_run, capsys, options, difference):
    csv = stopped_run / "dataset" / "measurements.csv"
    before = csv.read_bytes()
    assert main(["validate", "--resume", str(stopped_run), *options]) == 2
    err = capsys.readouterr().err
    assert f"--resume {stopped_run}: " in err and difference in err and "Traceback" not in err
    assert csv.read_bytes() == before


def test_every_difference_is_named_at_once(stopped_run, capsys):
    assert main(["validate", "--resume", str(stopped_run), "--seed", "5", "--set", "tendons.pretension_n=1.4"]) == 2
    err = capsys.readouterr().err
    for difference in ("--seed 5 here, 0 in the run", "tendons.pretension_n 1.4 here", "--quick off here, on"):
        assert difference in err


def test_resume_under_the_same_conditions_is_accepted(stopped_run, tmp_path):
    (stopped_run / commands.TWIN_TRUTH).write_text(json.dumps({"twin_set": ["effects.tension_gain_error=[0,0.1,0,0]"]}))
    args = build_parser().parse_args(["validate", "--quick", "--seed", "0", "--resume", str(stopped_run),
                                      "--twin-set", "effects.tension_gain_error=[0, 0.1, 0, 0]"])
    assert commands._check_resume(args, "validate", "validation", load_params()) == stopped_run


@pytest.mark.parametrize("where", ["empty", "dataset", "nowhere"])
def test_resume_of_a_folder_that_is_not_a_run_folder_is_refused(stopped_run, tmp_path, capsys, where):
    folder = {"empty": tmp_path / "empty", "dataset": stopped_run / "dataset", "nowhere": tmp_path / "nowhere"}[where]
    if where == "empty":
        folder.mkdir()
    assert main(["validate", "--quick", "--seed", "0", "--resume", str(folder)]) == 2
    assert f"--resume {folder}: not a run folder of twin validate" in capsys.readouterr().err


def test_resume_of_another_experiment_is_refused(stopped_run, capsys):
    assert main(["stiffness", "--seed", "0", "--resume", str(stopped_run)]) == 2
    assert "a twin validate run, not a twin stiffness run" in capsys.readouterr().err


def test_resume_of_a_dataset_torn_in_the_middle_is_refused_before_the_device_is_opened(stopped_run, capsys):
    csv = stopped_run / "dataset" / "measurements.csv"
    lines = csv.read_bytes().split(b"\r\n")
    lines[1] = lines[1][:30]
    csv.write_bytes(b"\r\n".join(lines))
    assert main(["validate", "--quick", "--seed", "0", "--resume", str(stopped_run)]) == 2
    assert "its dataset cannot be resumed" in capsys.readouterr().err


# --- run folders -----------------------------------------------------------------------------


def test_runs_started_in_the_same_second_get_their_own_folders(tmp_path, monkeypatch):
    class Frozen(datetime.datetime):
        @classmethod
        def now(cls, tz=None):
            return datetime.datetime(2024, 5, 1, 12, 0, 0)

    monkeypatch.setattr(cliargs.datetime, "datetime", Frozen)
    args = build_parser().parse_args(["validate", "--quick", "--out", str(tmp_path)])
    folders, errors = [], []

    def start():
        try:
            folders.append(commands._start_run(args, "validate"))
        except Exception as exc:  # collected: the assertion below names it
            errors.append(exc)

    threads = [threading.Thread(target=start) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    names = sorted(f.name for f in folders)
    assert names == sorted(["validate-20240501-120000"] + [f"validate-20240501-120000-{n}" for n in range(2, 7)])
    assert all(json.loads((f / commands.RUN_RECORD).read_text())["command"] == "validate" for f in folders)


# --- twin emulate --link ---------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["file", "dangling symlink"])
def test_emulate_link_refuses_an_existing_path(tmp_path, capsys, kind):
    path = tmp_path / "ttyTWIN"
    if kind == "file":
        path.write_text("precious")
    else:
        path.symlink_to(tmp_path / "gone")
    assert main(["emulate", "--link", str(path)]) == 2
    assert f"--link {path}: already exists" in capsys.readouterr().err
    assert path.read_text() == "precious" if kind == "file" else path.is_symlink()


def test_emulator_removes_only_the_link_it_made(tmp_path):
    from twin.device.pty_board import PtyBoard

    path = tmp_path / "ttyTWIN"
    board = PtyBoard(seed=1, link_path=path)
    board.plug()
    try:
        assert path.is_symlink()
        path.unlink()
        path.write_text("made by someone else meanwhile")
    finally:
        board.close()
    assert path.read_text() == "made by someone else meanwhile"


def test_emulator_link_never_replaces_what_appeared_at_the_path_nor_a_file_beside_it(tmp_path):
    # Before: PATH.new was deleted silently, and a file made at PATH after the command's check
    # was destroyed by the rename over it.
    from twin.device.pty_board import PtyBoard

    path = tmp_path / "ttyTWIN"
    beside = tmp_path / "ttyTWIN.new"
    beside.write_text("someone's file")
    path.write_text("made after the check")
    with pytest.raises(ValueError, match=f"link {path}: already exists"):
        PtyBoard(seed=1, link_path=path).plug()
    assert path.read_text() == "made after the check" and beside.read_text() == "someone's file"
    path.unlink()
    board = PtyBoard(seed=1, link_path=path)
    board.plug()
    try:
        assert path.is_symlink() and beside.read_text() == "someone's file"
    finally:
        board.close()
    assert not path.exists() and beside.read_text() == "someone's file"
