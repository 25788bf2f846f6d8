"""The validation sweep for any tendon layout: N-tendon datasets, and the configurations a
layout cannot realise named in the metadata, the report and the command's output.

The protocol is run on an ideal rig behind the device interface (exact PCC bending, noiseless
sensors), so these tests need neither the emulated board nor the twin. ``twin validate`` on the
twin itself, for each robot of the zoo, is at the end.
"""

import json
import types

import numpy as np
import pytest

from twin import load_params
from twin.cli import main
from twin.data.dataset import read_dataset
from twin.experiments.analysis import analyse_validation
from twin.experiments.protocols import UNREALISABLE, run_validation, unrealisable
from twin.experiments.report import write_validation_report
from twin.pcc import arc_tip_position_m, validation_grid
from twin.pose import HORIZONTAL
from twin.robots import load_robot
from twin.rod.grid import pcc_realisable, pcc_tensions_n

# Four curvatures (straight among them) in every plane of the grid, unloaded and with 10 g.
GRID = [g for g in validation_grid() if g[1] in (0.0, 8.7, 26.2) and g[3] in (0.0, 0.01)]
# Two antagonistic tendons: they bend in the plane 0°-180° only.
TWO = load_params(overrides={"tendons.angles_deg": [0.0, 180.0], "effects.tension_gain_error": [0.0] * 2,
                             "effects.tension_offset_error_n": [0.0] * 2,
                             "sensors.loadcell_offset_counts": [0.0] * 2})


class _Fixture:
    def __init__(self, rig):
        self.rig = rig

    def hang_tip_mass(self, mass_kg):
        self.rig.mass_kg = mass_kg

    def engage_holder(self):
        # The holder straightens the backbone: the encoders read the straight pose's lengths.
        self.rig.held = True
        self.rig.lengths_m = np.full(self.rig.tendons, IdealRig.STRAIGHT_M)

    def release_holder(self):
        self.rig.held = False

    def hang_calibration_mass(self, mass_g, channels):
        assert sorted(channels) == list(range(self.rig.tendons)), "the weights go on every tendon of the robot"

    def remove_calibration_masses(self):
        pass


class IdealRig:
    """A rig behind the device interface that bends exactly to the PCC shape its length
    setpoints describe, and checks that they describe one (one κ and φ for every tendon)."""

    url = "ideal://"
    rate_hz = 100.0
    # The encoders' reading of the straight backbone (m): not their zero, as on the rig.
    STRAIGHT_M = 2e-4

    def __init__(self, params):
        self.params = params
        self.tendons = params.tendons.count
        self.base_rotation = HORIZONTAL
        self.fixture = _Fixture(self)
        self.tracker = self
        self.time_s = 0.0
        self.lengths_m = np.full(self.tendons, self.STRAIGHT_M)
        self.kappa, self.phi_rad, self.mass_kg, self.held = 0.0, 0.0, 0.0, True
        self.setpoints = []
        self.info = types.SimpleNamespace(tendon_m_per_count=params.rig.tendon_m_per_count)
        self._received = []

    def disable(self):
        pass

    def enable(self):
        pass

    def set_mode(self, mode):
        assert mode == "lengths"

    def wait(self, duration_s):
        self.time_s += duration_s

    def tare(self, *, loadcells=True, lengths=True):
        pass

    def set_lengths(self, lengths_m):
        change = np.asarray(lengths_m) - self.STRAIGHT_M
        assert change.shape == (self.tendons,)
        # Δℓ_i = −r s_i (κ cos φ cos α_i + κ sin φ sin α_i): solve for (κ cos φ, κ sin φ).
        p = self.params
        alpha = np.radians(p.tendons.angles_deg)
        s = np.asarray(p.tendon_ends_m())
        a = -p.tendons.radius_m * s[:, None] * np.stack([np.cos(alpha), np.sin(alpha)], axis=1)
        (c, d), *_ = np.linalg.lstsq(a, change, rcond=None)
        assert np.allclose(a @ [c, d], change, atol=1e-12), "the setpoints do not bend the backbone to one arc"
        self.kappa, self.phi_rad = float(np.hypot(c, d)), float(np.arctan2(d, c))
        self.lengths_m = np.asarray(lengths_m, dtype=float)
        self.setpoints.append((self.kappa, np.degrees(self.phi_rad) % 360.0))

    def _sample(self):
        kappa, phi = (0.0, 0.0) if self.held else (self.kappa, np.degrees(self.phi_rad))
        tensions = pcc_tensions_n(kappa, phi, self.params)
        counts = np.round(self.lengths_m / self.info.tendon_m_per_count)
        return types.SimpleNamespace(tensions_n=tensions, tendon_lengths_m=self.lengths_m.copy(),
                                     encoder_counts=counts, raw_counts=np.zeros(self.tendons), fault_flags=0,
                                     state="enabled", time_s=self.time_s)

    def latest(self):
        return self._sample()

    def wait_next(self, timeout_s=1.0):
        self.time_s += 1.0 / self.rate_hz
        self._received.append(self._sample())
        return self._received[-1]

    def drain(self):
        received, self._received = self._received, []
        return received

    def read(self):
        tip = arc_tip_position_m(self.kappa, np.degrees(self.phi_rad), self.params.backbone.length_m)
        pose = types.SimpleNamespace(position_m=self.base_rotation @ tip, rotation=np.eye(3))
        return types.SimpleNamespace(ok=True, pose=pose, reason="")


@pytest.mark.parametrize("robot", ["three-tendon", "two-segment"])
def test_the_sweep_realises_every_plane_of_a_layout_that_can_bend_them_all(tmp_path, robot):
    params = load_robot(robot)
    rig = IdealRig(params)
    run_validation(rig, tmp_path, params, grid=GRID, progress=False, robot=robot)
    d = read_dataset(tmp_path)
    assert d.tendons == params.tendons.count and d.robot == robot
    assert d.tensions_n.shape == (len(GRID), params.tendons.count)
    assert sorted(d["config"]) == [g[0] for g in GRID] and d.metadata["left_out"] == []
    # Each bent configuration was driven to its own κ and φ (the rig checks it is one arc).
    bent = sorted({(k, p) for _, k, p, _ in GRID if k > 0})
    realised = sorted({(round(k, 9), round(p, 6) % 360.0) for k, p in rig.setpoints if k > 1e-9})
    assert realised == [(round(k, 9), p) for k, p in bent]
    # The lengths recorded are the setpoints' (less the straight pose's zero): 0 when straight.
    straight = d["kappa_cmd_per_m"] == 0
    assert np.allclose(d.lengths_m[straight], 0.0) and not np.allclose(d.lengths_m[~straight], 0.0)


def test_the_configurations_a_layout_cannot_realise_are_left_out_and_recorded(tmp_path):
    left_out = unrealisable(GRID, TWO)
    assert left_out and all(e["kappa_cmd_per_m"] > 0 and not pcc_realisable(e["phi_cmd_deg"], TWO)
                            for e in left_out)
    assert {e["phi_cmd_deg"] for e in left_out} == set(range(0, 360, 30)) - {0, 180}
    assert all(e["reason"] == UNREALISABLE for e in left_out)
    run_validation(IdealRig(TWO), tmp_path / "data", TWO, grid=GRID, progress=False, robot="two-tendon")
    d = read_dataset(tmp_path / "data")
    assert d.metadata["left_out"] == left_out
    assert sorted(d["config"]) == sorted({g[0] for g in GRID} - {e["config"] for e in left_out})
    # The report says so, and lists each of them.
    path = write_validation_report(analyse_validation(d, TWO), tmp_path / "report")
    text = path.read_text()
    assert f"**{len(left_out)} configurations of the grid left out**" in text
    section = text.split("## Configurations left out", 1)[1]
    assert all(f"| {e['config']} |" in section for e in left_out)
    assert json.loads((tmp_path / "report" / "summary.json").read_text())["left_out"] == len(left_out)


def test_a_robot_that_can_realise_the_whole_grid_leaves_nothing_out():
    for robot in ("endoscope", "three-tendon", "two-segment"):
        assert unrealisable(validation_grid(), load_robot(robot)) == []


def test_a_resume_with_a_robot_of_another_tendon_count_is_refused_in_one_line(tmp_path, capsys):
    from twin.data.dataset import DatasetWriter

    run = tmp_path / "validate-run"
    with DatasetWriter(run / "dataset", experiment="validation", device="sim://", params=load_robot("three-tendon"),
                       base_rotation=HORIZONTAL, robot="three-tendon"):
        pass
    code = main(["validate", "--resume", str(run), "--robot", "endoscope"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err == f"twin validate: --resume {run}: dataset {run / 'dataset'} has 3 tendons; robot 'endoscope' has 4"


def test_a_calibration_file_of_another_channel_count_is_refused_before_a_run_folder_exists(tmp_path, capsys):
    from twin.calibration import Calibration, fit_all

    tensions = np.array([0.0, 1.0, 2.0])
    raw = np.outer(tensions, [1000.0] * 4) + 5.0
    path = tmp_path / "cal.json"
    Calibration.from_fits(fit_all(raw, tensions), raw, masses_g=[0.0, 102.0, 204.0], gravity_m_s2=9.81,
                          samples_per_mass=1, device="sim://").save(path)
    code = main(["validate", "--robot", "three-tendon", "--quick", "--calibration", str(path),
                 "--out", str(tmp_path / "runs")])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"twin validate: --calibration {path}: 4 channels; robot "
                                               "'three-tendon' has 3 tendons")
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_the_cocontraction_study_refuses_a_robot_without_an_antagonistic_pair_before_touching_the_device():
    from twin.control.cocontraction import run_cocontraction_study

    # Three tendons within a quarter turn: none opposes another.
    fan = load_robot("three-tendon").replace({"tendons.angles_deg": [0.0, 45.0, 90.0]})
    with pytest.raises(ValueError, match=r"tendons.angles_deg = \[0.0, 45.0, 90.0\]: no two tendons .* more than "
                                         r"90 deg apart; the robot has no antagonistic pair"):
        run_cocontraction_study(None, fan)


def test_an_n_tendon_dataset_exports_one_joint_per_tendon(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from twin.rosbag import TENDONS_TOPIC, export_bag

    params = load_robot("two-segment")
    run_validation(IdealRig(params), tmp_path / "data", params, grid=GRID[:6], progress=False, robot="two-segment")
    export_bag(tmp_path / "data", tmp_path / "out.mcap")
    with open(tmp_path / "out.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        joints = [m for _, c, _, m in reader.iter_decoded_messages() if c.topic == TENDONS_TOPIC]
        stream.seek(0)
        meta = {m.name: m.metadata for m in make_reader(stream).iter_metadata()}["twin_dataset"]
    d = read_dataset(tmp_path / "data")
    assert [list(j.name) for j in joints] == [[f"tendon_{i}" for i in range(1, 7)]] * len(d)
    assert np.allclose([j.effort for j in joints], d.tensions_n) and np.allclose([j.position for j in joints],
                                                                                   d.lengths_m)
    assert meta["tendons"] == "6" and meta["robot"] == "two-segment"
