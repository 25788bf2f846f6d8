"""Independent jobs on one core, on local processes or on a Ray cluster, results in job order.

Sweeps (the zoo cross-check, one job per robot) and controller tuning (one job per tracking
episode) are many independent, CPU-bound jobs of seconds to minutes each. :func:`map_ordered`
(or an :class:`Executor`, whose processes serve many lists of jobs) runs them:

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
import os
import socket
from typing import Any, Callable, Iterable, TypeVar

__all__ = ["ClusterError", "Executor", "connect", "disconnect", "map_ordered"]

Job = TypeVar("Job")
Result = TypeVar("Result")

# Seconds to wait for a cluster head to accept a connection before saying it is not there;
# ray.init would otherwise retry for a minute.
_CONNECT_TIMEOUT_S = 5.0
# The address Ray is connected to in this process, if any.
_connected: str | None = None


class ClusterError(OSError):
    """``--cluster`` cannot be used: Ray is not installed, or no Ray head answers at the address."""


class Executor:
    """Runs lists of jobs, results in job order, on the same processes from one list to the next.

    A fit that evaluates a cost of a few parallel jobs many times opens one (``with
    Executor(...) as executor``) rather than starting processes for each evaluation.

    Args:
        workers: local processes (1: this process); with ``cluster="local"`` the CPUs of the
            local Ray instance; ignored for a cluster address, whose CPUs decide.
        cluster: a Ray head address (see the module), or None for local processes.

    Raises:
        ValueError: ``workers`` < 1.
        ClusterError: ``cluster`` is given and Ray is not installed or the head does not answer.
    """

    def __init__(self, workers: int = 1, cluster: str | None = None):
        if workers < 1:
            raise ValueError(f"workers = {workers!r}: expected at least 1")
        self.workers, self.cluster = workers, cluster
        self._ray = connect(cluster, workers) if cluster is not None else None
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[Job], Result], jobs: Iterable[Job]) -> list[Result]:
        """``[fn(job) for job in jobs]``; ``fn`` a module-level function (pickled by reference to the
        processes and nodes), each job a picklable argument that carries its own seed."""
        jobs = list(jobs)
        if self._ray is not None:
            remote = _remote(fn)
            return self._ray.get([remote.remote(job) for job in jobs])
        if self.workers == 1 or len(jobs) <= 1:
            return [fn(job) for job in jobs]
        if self._pool is None:
            self._pool = concurrent.futures.ProcessPoolExecutor(min(self.workers, len(jobs)))
        return list(self._pool.map(fn, jobs))

    def close(self) -> None:
        """Stop the local processes (a cluster stays joined: :func:`disconnect` leaves it)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def map_ordered(fn: Callable[[Job], Result], jobs: Iterable[Job], *, workers: int = 1,
                cluster: str | None = None) -> list[Result]:
    """``[fn(job) for job in jobs]``, run in parallel when asked: one :meth:`Executor.map`.

    Args:
        fn: a module-level function (pickled by reference to the processes and nodes).
        jobs: the jobs, each a picklable argument of ``fn`` that carries its own seed.
        workers, cluster: as :class:`Executor` takes them.

    Returns:
        The results in the order of ``jobs``.

    Raises:
        ValueError: ``workers`` < 1.
        ClusterError: ``cluster`` is given and Ray is not installed or the head does not answer.
    """
    with Executor(workers, cluster) as executor:
        return executor.map(fn, jobs)


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
    options: dict[str, Any]
    if cluster == "local":
        options = {"num_cpus": workers, "include_dashboard": False}
    else:
        if cluster != "auto":
            _check_reachable(cluster)
        options = {"address": cluster}
    try:
        if cluster == "local":
            _init_on_loopback(ray, options)
        else:
            ray.init(logging_level=logging.WARNING, **options)
    except ConnectionError as exc:
        raise ClusterError(f"--cluster {cluster}: no Ray cluster there ({exc})") from None
    _connected = cluster
    return ray


def _init_on_loopback(ray, options: dict) -> None:
    """Start a local Ray instance whose every server (GCS, raylet, workers, agents) listens on
    127.0.0.1 only: by default on Linux they listen on all interfaces, open to the network.

    Ray takes a loopback node address only where it does not support clusters (its Windows and
    macOS default); it is made to here for the start, then set back, so a later ``--cluster
    ADDRESS`` in the same process joins a real cluster as usual.
    """
    from ray._private import ray_constants

    saved_constant = ray_constants.ENABLE_RAY_CLUSTER
    saved_env = os.environ.get(ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR)
    ray_constants.ENABLE_RAY_CLUSTER = False
    os.environ[ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR] = "0"  # the processes Ray starts read it too
    try:
        ray.init(logging_level=logging.WARNING, _node_ip_address="127.0.0.1", **options)
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = saved_constant
        if saved_env is None:
            os.environ.pop(ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR, None)
        else:
            os.environ[ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR] = saved_env


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
