"""The one finite-vector check: what it accepts, and the one-line error naming argument and value."""

import numpy as np
import pytest

from twin.checks import finite_vector


@pytest.mark.parametrize("value", [[1, 2, 3], (1.0, 2.0, 3.0), np.array([1.0, 2.0, 3.0]), np.array([[1.0], [2.0], [3.0]])])
def test_n_finite_numbers_in_any_form_are_a_float_array(value):
    out = finite_vector("x_m", value, 3)
    assert out.dtype == float and out.shape == (3,) and out.tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize("value, shown", [([1.0, 2.0], r"\[1.0, 2.0\]"), ([1.0, float("nan"), 3.0], r"\[1.0, nan, 3.0\]"),
                                          (np.array([1.0, np.inf, 0.0]), r"\[1.0, inf, 0.0\]"), ("abc", "'abc'"),
                                          ([[1.0, 2.0], [3.0]], r"\[\[1.0, 2.0\], \[3.0\]\]"), (None, "None")])
def test_anything_else_is_refused_naming_the_argument_and_value(value, shown):
    with pytest.raises(ValueError, match=rf"^tensions_n = {shown}: expected 3 finite numbers$"):
        finite_vector("tensions_n", value, 3)


def test_the_message_says_what_the_numbers_are():
    with pytest.raises(ValueError, match="expected 2 finite counts"):
        finite_vector("read_raw_counts()", [1.0], 2, what="counts")
