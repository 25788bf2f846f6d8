"""Input files that cannot eat memory: parameter, calibration and dataset files are read only from
regular files under a size cap, and anything else is refused in one line naming the file."""

import os
import subprocess
import sys

import pytest

from twin.calibration import CalibrationFileError, load_calibration
from twin.data.dataset import DatasetError, read_dataset
from twin.inputs import PARAMS_MAX_BYTES, InputFileError, read_input
from twin.params import ParameterError, load_params


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "fifo"
    os.mkfifo(path)
    return path


def test_a_device_a_fifo_and_a_folder_are_refused_without_reading(tmp_path, fifo):
    # Before: --params /dev/zero grew memory without bound (3.5 GB in 30 s); a FIFO hung.
    for path, kind in (("/dev/zero", "a device"), (fifo, "a FIFO"), (tmp_path, "a folder")):
        with pytest.raises(InputFileError, match=f"^{path}: {kind}, not a regular file"):
            read_input(path, max_bytes=100)


def test_a_file_over_its_cap_is_refused_and_one_at_it_is_read(tmp_path):
    path = tmp_path / "f"
    path.write_bytes(b"x" * 100)
    assert read_input(path, max_bytes=100) == b"x" * 100
    with pytest.raises(InputFileError, match="100 bytes, more than the 99"):
        read_input(path, max_bytes=99)


def test_each_reader_names_the_file(tmp_path):
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (PARAMS_MAX_BYTES + 1))
    with pytest.raises(ParameterError, match=f"^{big}: .*more than"):
        load_params(big)
    with pytest.raises(ParameterError, match="^/dev/zero: a device"):
        load_params("/dev/zero")
    with pytest.raises(CalibrationFileError, match="^/dev/zero: a device"):
        load_calibration("/dev/zero")
    binary = tmp_path / "cal.bin"
    binary.write_bytes(bytes(range(256)))
    # Before: a one-line error that did not name the file.
    with pytest.raises(CalibrationFileError, match=f"^{binary}: .*not UTF-8"):
        load_calibration(binary)
    dataset = tmp_path / "ds"
    dataset.mkdir()
    os.symlink("/dev/zero", dataset / "metadata.json")
    with pytest.raises(DatasetError, match="metadata.json: a device"):
        read_dataset(dataset)


@pytest.mark.parametrize("argv", [["predict", "--params", "/dev/zero", "--tensions", "1,1,1,1"],
                                  ["validate", "--calibration", "/dev/zero", "--device", "sim://"]])
def test_the_command_line_refuses_dev_zero_in_one_line(argv, tmp_path):
    result = subprocess.run([sys.executable, "-m", "twin.cli", *argv, "--out", str(tmp_path / "out")]
                            if argv[0] == "validate" else [sys.executable, "-m", "twin.cli", *argv],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert len(result.stderr.strip().splitlines()) == 1 and "/dev/zero: a device" in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()


def test_discrepancy_warns_in_one_line_of_a_parameter_file_of_another_robot(capsys):
    # Before: it started fitting without a word. (--twin-set without sim:// stops it right after.)
    from pathlib import Path

    from twin.cli import main
    from twin.resources import resource_path

    dataset = Path(__file__).parent / "golden" / "dataset_v1"
    same, other = resource_path("models") / "endoscope" / "endoscope.toml", resource_path("models") / "long" / "long.toml"
    for params, warned in ((same, False), (other, True)):
        assert main(["discrepancy", str(dataset), "--params", str(params), "--twin-set",
                     "effects.tendon_friction_coeff=0.3"]) != 0
        lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
        assert len(lines) == warned and (not warned or "backbone.length" in lines[0])
