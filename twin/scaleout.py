"""Independent jobs on one core, on local processes or on a Ray cluster, results in job order.

Sweeps (the zoo cross-check, one job per robot) and controller tuning (one job per tracking
episode) are many independent, CPU-bound jobs of seconds to minutes each. :func:`map_ordered`
runs them:

- ``workers=1`` and no cluster: one after the other in this process (no pickling, easiest to
  debug);
- ``workers=N``: in a pool of N local processes (:class:`concurrent.futures.ProcessPoolExecutor`);
- ``cluster=ADDRESS``: as Ray tasks on the cluster whose head is at ``ADDRESS`` (``HOST:PORT``
  or ``ray://HOST:PORT``; ``auto`` for the cluster already running on this machine, ``local``
  for a new single-machine one of ``workers`` CPUs). Ray is an optional dependency
  (``pip install 'twin[cluster]'``) and must be installed, with this package at the same
  version, on every node.

Ray rather than Dask or a batch queue: it schedules Python functions on a cluster with no
shared file system, and a one-command head (``ray start --head``) is the whole set-up.

The results are the same whatever runs them: a job carries everything it depends on, its seed
included, and no job draws from a random generator another job shares, so the same jobs give
the same results on one core, in several processes and on the cluster. A job is a module-level
function and picklable arguments; it returns its result rather than writing files, since a
cluster node does not share this machine's disk.
"""

from __future__ import annotations

import concurrent.futures
import functools
import logging
import socket
from typing import Any, Callable, Iterable, TypeVar

__all__ = ["ClusterError", "connect", "disconnect", "map_ordered"]

Job = TypeVar("Job")
Result = TypeVar("Result")

# Seconds to wait for a cluster head to accept a connection before saying it is not there;
# ray.init would otherwise retry for a minute.
_CONNECT_TIMEOUT_S = 5.0
# The address Ray is connected to in this process, if any.
_connected: str | None = None


class ClusterError(OSError):
    """``--cluster`` cannot be used: Ray is not installed, or no Ray head answers at the address."""


def map_ordered(fn: Callable[[Job], Result], jobs: Iterable[Job], *, workers: int = 1,
                cluster: str | None = None) -> list[Result]:
    """``[fn(job) for job in jobs]``, run in parallel when asked.

    Args:
        fn: a module-level function (pickled by reference to the processes and nodes).
        jobs: the jobs, each a picklable argument of ``fn`` that carries its own seed.
        workers: local processes (1: this process); with ``cluster="local"`` the CPUs of the
            local Ray instance; ignored for a cluster address, whose CPUs decide.
        cluster: a Ray head address (see the module), or None for local processes.

    Returns:
        The results in the order of ``jobs``.

    Raises:
        ValueError: ``workers`` < 1.
        ClusterError: ``cluster`` is given and Ray is not installed or the head does not answer.
    """
    if workers < 1:
        raise ValueError(f"workers = {workers!r}: expected at least 1")
    jobs = list(jobs)
    if cluster is not None:
        ray = connect(cluster, workers)
        remote = _remote(fn)
        return ray.get([remote.remote(job) for job in jobs])
    if workers == 1 or len(jobs) <= 1:
        return [fn(job) for job in jobs]
    with concurrent.futures.ProcessPoolExecutor(min(workers, len(jobs))) as pool:
        return list(pool.map(fn, jobs))


def disconnect() -> None:
    """Leave the Ray cluster this process joined (a ``local`` one stops); nothing if none."""
    global _connected
    if _connected is not None:
        import ray

        ray.shutdown()
        _connected = None


def connect(cluster: str, workers: int = 1) -> Any:
    """Join the Ray cluster at ``cluster`` (once per process and address): what
    :func:`map_ordered` does first, for a command to fail before it makes a report folder.

    Args:
        cluster: a Ray head address (see the module).
        workers: the CPUs of the Ray instance ``cluster="local"`` starts.

    Returns:
        The ``ray`` module.

    Raises:
        ClusterError: Ray is not installed or the head does not answer.
    """
    global _connected
    try:
        import ray
    except ImportError:
        raise ClusterError(f"--cluster {cluster}: Ray is not installed (pip install 'twin[cluster]')") from None
    if _connected == cluster and ray.is_initialized():
        return ray
    disconnect()
    if cluster == "local":
        options = {"num_cpus": workers, "include_dashboard": False}
    else:
        if cluster != "auto":
            _check_reachable(cluster)
        options = {"address": cluster}
    try:
        ray.init(logging_level=logging.WARNING, **options)
    except ConnectionError as exc:
        raise ClusterError(f"--cluster {cluster}: no Ray cluster there ({exc})") from None
    _connected = cluster
    return ray


def _check_reachable(address: str) -> None:
    """Raise :class:`ClusterError` unless something accepts TCP connections at ``[ray://]HOST:PORT``."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"--cluster {address}: expected HOST:PORT, ray://HOST:PORT, auto or local")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise ClusterError(f"--cluster {address}: no Ray head answers there ({exc.strerror or exc})") from None


@functools.lru_cache(maxsize=None)
def _remote(fn: Callable) -> Any:
    """``fn`` as a Ray remote function of one CPU, made once per function."""
    import ray

    return ray.remote(num_cpus=1)(fn)
