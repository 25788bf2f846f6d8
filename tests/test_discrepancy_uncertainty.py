"""The honest uncertainty of a fitted value (twin.discrepancy.uncertainty): its terms, how the
model-form term scales, and where it covers what the statistical interval misses."""

import math

import numpy as np
import pytest

from twin import load_params
from twin.data.fitting import fit_parameters
from twin.discrepancy import candidate_library, synthetic_validation_dataset
from twin.discrepancy.uncertainty import LEVEL_SIGMA, PATTERNS, honest_uncertainty, model_form_reference
from twin.pcc import validation_grid

NOMINAL = load_params()
GRID = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]


@pytest.fixture(scope="module")
def tilted(tmp_path_factory):
    """A predictor-made sweep with a hidden 0.8° base tilt, fitted with the tilt's own candidate."""
    truth = NOMINAL.replace({"effects.base_tilt_deg": [0.8, -0.5]})
    data = synthetic_validation_dataset(tmp_path_factory.mktemp("tilt"), NOMINAL, truth, grid=GRID, seed=4)
    parameters = candidate_library(NOMINAL)["base_tilt"].parameters
    return data, fit_parameters(data, NOMINAL, parameters, max_evaluations=25), [0.8, -0.5]


def test_terms_add_in_quadrature_and_the_model_form_term_scales_with_its_level(tilted):
    data, fit, truth = tilted
    none = honest_uncertainty(data, fit, model_form_m=0.0, splits=3)
    some = honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=3)
    more = honest_uncertainty(data, fit, model_form_m=0.1e-3, structured_rms_m=0.34e-3, splits=3)
    for a, b, c, se in zip(none, some, more, fit.std_errors):
        assert a.model_form == 0.0 and a.std_error == pytest.approx(se)
        # The same halves: the scatter is the fit's, not the level's.
        assert b.split_scatter == a.split_scatter > 0
        # The larger of the given level and the structure left is taken, linearly.
        assert c.model_form == pytest.approx(2 * b.model_form, rel=1e-9)
        assert b.total == pytest.approx(math.sqrt(se**2 + b.split_scatter**2 + b.model_form**2))
        low, high = b.interval()
        assert low == pytest.approx(b.value - LEVEL_SIGMA * b.total) and high > b.value + LEVEL_SIGMA * se
        d = b.to_dict()
        assert d["ci95"] == pytest.approx([low, high]) and d["ci95_statistical"][0] > low
    # On data the predictor made (no model-form error) its intervals hold the truth.
    assert all(u.interval()[0] < t < u.interval()[1] for u, t in zip(some, truth))


def test_repeats_shrink_the_standard_error_but_not_the_model_form_term(tilted, tmp_path):
    """f = se / σ · m · √R: repeated rows halve se's square but not f, as a model-form error is the
    configuration's, the same on its repeats."""
    data, fit, _ = tilted
    truth = NOMINAL.replace({"effects.base_tilt_deg": [0.8, -0.5]})
    twice = synthetic_validation_dataset(tmp_path, NOMINAL, truth, grid=GRID, seed=5, repeats=2)
    refit = fit_parameters(twice, NOMINAL, fit.parameters, x0=fit.values, max_evaluations=25)
    for u, v in zip(honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=2),
                    honest_uncertainty(twice, refit, model_form_m=0.17e-3, splits=2)):
        assert v.std_error == pytest.approx(u.std_error / math.sqrt(2), rel=0.2)
        assert v.model_form == pytest.approx(u.model_form, rel=0.2)


def test_bad_levels_and_splits_are_refused(tilted):
    data, fit, _ = tilted
    with pytest.raises(ValueError, match="splits"):
        honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=1)
    with pytest.raises(ValueError, match="model_form_m"):
        honest_uncertainty(data, fit, model_form_m=float("nan"))
    with pytest.raises(ValueError, match="structured_rms_m"):
        honest_uncertainty(data, fit, model_form_m=0.0, structured_rms_m=-1.0)


def test_beyond_a_sixth_of_the_thesis_grid_more_configurations_do_not_shrink_the_model_form_term(tmp_path):
    """A model-form error is smooth over the workspace: over 72 configurations (every plane) f
    counts 36 independent ones, so it is √2 wider than se / σ · m alone, not equal to it."""
    grid = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[3] in (0.0, 0.01)]
    truth = NOMINAL.replace({"effects.base_tilt_deg": [0.8, -0.5]})
    data = synthetic_validation_dataset(tmp_path, NOMINAL, truth, grid=grid, seed=6)
    fit = fit_parameters(data, NOMINAL, candidate_library(NOMINAL)["base_tilt"].parameters, max_evaluations=25)
    assert len(data) == 72 > PATTERNS
    for u, se in zip(honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=2), fit.std_errors):
        assert u.model_form == pytest.approx(se / fit.residual_sigma_m * 0.17e-3 * math.sqrt(72 / PATTERNS), rel=1e-9)


def test_the_model_form_shift_is_what_the_fit_reads_off_for_the_reference_error(tilted):
    """An error d = J·δ in the residuals moves a least-squares fit by −δ: b is that move, and
    it adds to u in quadrature."""
    data, fit, _ = tilted
    delta = [0.05, -0.03]  # degrees of tilt about x and y
    reference = (fit.jacobian @ delta).reshape(-1, 3)
    plain = honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=2)
    shifted = honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=2, reference_errors_m=reference)
    for u, v, d in zip(plain, shifted, delta):
        assert u.model_form_shift == 0.0
        assert v.model_form_shift == pytest.approx(-d, rel=1e-6)
        assert v.total == pytest.approx(math.sqrt(u.total**2 + d**2))
        assert v.to_dict()["model_form_shift"] == v.model_form_shift
    with pytest.raises(ValueError, match="reference_errors_m"):
        honest_uncertainty(data, fit, model_form_m=0.17e-3, splits=2, reference_errors_m=reference[1:])


def test_the_model_form_reference_is_the_twin_against_the_predictor_at_each_rows_command(tilted):
    from twin.sim.crosscheck import crosscheck

    data, _, _ = tilted
    reference = model_form_reference(data, NOMINAL)
    assert reference.shape == (len(data), 3)
    # The endoscope's twin and predictor differ by 0.04 mm median, 0.17 mm at worst (reports/crosscheck).
    size = np.linalg.norm(reference, axis=1)
    assert 0.005e-3 < np.median(size) < 0.1e-3 and size.max() < 0.2e-3
    row = int(np.argmax(size))
    command = (0, float(data["kappa_cmd_per_m"][row]), float(data["phi_cmd_deg"][row]), float(data["tip_mass_kg"][row]))
    one = crosscheck(NOMINAL, configs=[command])
    # The twin settles to 1 µm per 20 ms from wherever the configuration before left it: a few µm.
    assert reference[row] == pytest.approx(one.rod_tip_m[0] - one.twin_tip_m[0], abs=5e-6)
