"""Argument checks shared by the library's entry points: a refused value raises a ValueError whose
one line names the argument and the value (the ``twin`` command prints it as it is)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["finite_vector"]


def finite_vector(name: str, value: object, n: int, *, what: str = "numbers") -> np.ndarray:
    """``value`` as a float array of shape (n,): any sequence or array of exactly ``n`` finite
    numbers (an (n, 1) column too).

    Args:
        name: the argument's name, for the message.
        value: what the caller passed.
        n: how many numbers.
        what: what the numbers are, for the message (``"counts"``).

    Raises:
        ValueError: ``"{name} = {value!r}: expected {n} finite {what}"``.
    """
    try:
        array = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        array = None
    # math.isfinite over a list: on the few numbers of a solve's input, several times faster than
    # np.isfinite(...).all(), and the predictor's warm solve checks its inputs every call.
    if array is None or array.size != n or not all(map(math.isfinite, array.tolist())):
        shown = value.tolist() if isinstance(value, np.ndarray) else value
        raise ValueError(f"{name} = {shown!r}: expected {n} finite {what}")
    return array
