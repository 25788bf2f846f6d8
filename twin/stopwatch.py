"""CPU time and wall time side by side, for the speed benchmarks (``twin bench``).

The benchmarks judge their goals on CPU time (:func:`time.process_time`: this process, all its
threads), which other work on a shared machine hardly changes, and print the wall time beside
it: on a loaded machine the wall clock runs several times the CPU time, and a goal judged on it
would fail a healthy build.
"""

from __future__ import annotations

import time

__all__ = ["Stopwatch"]


class Stopwatch:
    """``with Stopwatch() as watch: ...`` leaves ``watch.cpu_s`` and ``watch.wall_s`` (s)."""

    cpu_s: float = 0.0
    wall_s: float = 0.0

    def __enter__(self) -> "Stopwatch":
        self._wall = time.perf_counter()
        self._cpu = time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.cpu_s = time.process_time() - self._cpu
        self.wall_s = time.perf_counter() - self._wall
