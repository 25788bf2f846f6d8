"""The twin against the predictor on a few configurations of the thesis grid (the full grid and
the cause studies are `twin crosscheck`, reports/crosscheck/)."""

import numpy as np

from twin.params import load_params
from twin.sim.crosscheck import crosscheck, write_report

# Both tendon planes and one between them, the largest curvature, with and without a tip mass.
CONFIGS = [(180, 26.2, 0.0, 0.0), (197, 26.2, 150.0, 0.01), (117, 13.0, 90.0, 0.0), (2, 0.0, 0.0, 0.01)]


def test_at_the_defaults_the_twin_agrees_with_the_predictor_well_under_a_percent_of_length():
    result = crosscheck(configs=CONFIGS)
    assert result.settled.all() and result.rod_converged.all()
    # The twin stands in for the rig in the discrepancy workflow, which must find nothing in
    # twin data with every effect off: half a percent of L is 0.3 mm, near the tracker noise.
    assert np.all(result.difference_m < 0.005 * result.length_m)


def test_disc_routing_bends_further_than_the_predictor_and_the_report_says_so(tmp_path):
    params = load_params()
    continuous = crosscheck(params, configs=CONFIGS[:1])
    discs = crosscheck(params, configs=CONFIGS[:1], tendon_sites="discs")
    # The pretensioned chords pull the tip further round the bend, away from the clamp axis.
    assert discs.difference_m[0] > 10 * continuous.difference_m[0]
    assert discs.twin_tip_m[0][0] < continuous.twin_tip_m[0][0]
    path = write_report(continuous, [("disc routing", False, discs)], tmp_path, params)
    text = path.read_text()
    assert "| disc routing |" in text and (tmp_path / "crosscheck.csv").read_text().count("\n") == 2
