"""Sweeps and tuning on one core, on local processes and on a Ray head: the same jobs, the same results."""

import os
import pickle
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from twin import scaleout
from twin.cli import main
from twin.sim.crosscheck import QUICK_GRID, run_zoo
from twin.tuning import tracking_cost, tune_tracking_gains

TRACKER = {"gain": 0.0165, "velocity_gain_s": 0.16}
# Two robots that are not the default one, so that the zoo runs no cause studies.
ZOO_ROBOTS = ["three-tendon", "long"]


def _square_after_a_wait(x):
    """x² and the process it ran in; the first jobs wait longest, so a pool finishes them last."""
    time.sleep(0.05 * (4 - x))
    return x * x, os.getpid()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _zoo_csvs(out: Path) -> dict[str, str]:
    return {name: (out / name / "crosscheck.csv").read_text() for name in ZOO_ROBOTS}


def test_results_come_back_in_job_order_from_several_processes():
    results = scaleout.map_ordered(_square_after_a_wait, range(4), workers=2)
    assert [r for r, _ in results] == [0, 1, 4, 9]
    assert len({pid for _, pid in results} - {os.getpid()}) == 2
    assert scaleout.map_ordered(_square_after_a_wait, range(4)) == [(x * x, os.getpid()) for x in range(4)]


def test_an_executor_serves_every_list_of_jobs_from_the_same_processes():
    with scaleout.Executor(workers=2) as executor:
        first = {pid for _, pid in executor.map(_square_after_a_wait, range(4))}
        again = {pid for _, pid in executor.map(_square_after_a_wait, range(4))}
    assert len(first | again) <= 2 and os.getpid() not in first


def test_no_workers_is_refused():
    with pytest.raises(ValueError, match="workers = 0"):
        scaleout.map_ordered(abs, [1], workers=0)


def test_a_cluster_without_ray_installed_is_said_in_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(scaleout.ClusterError, match=r"Ray is not installed \(pip install 'twin\[cluster\]'\)"):
        scaleout.map_ordered(abs, [1], cluster="127.0.0.1:6379")


def test_an_unreachable_cluster_ends_the_commands_in_one_line_before_any_work(tmp_path, capsys):
    pytest.importorskip("ray", reason="ray is in the test extra: pip install -e '.[test]'")
    address = f"127.0.0.1:{_free_port()}"
    start = time.perf_counter()
    assert main(["crosscheck", "--robot", "all", "--quick", "--cluster", address, "--out", str(tmp_path / "x")]) == 1
    assert main(["tune", "--quick", "--cluster", address]) == 1
    assert time.perf_counter() - start < 10
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("twin") and line.endswith(
        f"--cluster {address}: no Ray head answers there (Connection refused)") for line in err)
    assert not (tmp_path / "x").exists()
    with pytest.raises(scaleout.ClusterError, match="expected HOST:PORT"):
        scaleout.connect("head-without-port")


def test_workers_spread_only_the_robots_of_the_zoo(capsys):
    assert main(["crosscheck", "--robot", "long", "--workers", "2"]) == 2
    assert "--workers and --cluster spread the robots of --robot all" in capsys.readouterr().err


def test_local_processes_give_what_one_core_gives(tmp_path):
    one = tracking_cost(TRACKER, seeds=(0, 1), steps=40, workers=1)
    assert tracking_cost(TRACKER, seeds=(0, 1), steps=40, workers=2) == one
    _, serial = run_zoo(tmp_path / "serial", configs=QUICK_GRID, robots=ZOO_ROBOTS)
    _, pooled = run_zoo(tmp_path / "pooled", configs=QUICK_GRID, robots=ZOO_ROBOTS, workers=2)
    assert pooled == serial and list(pooled) == ZOO_ROBOTS
    assert _zoo_csvs(tmp_path / "pooled") == _zoo_csvs(tmp_path / "serial")
    assert (tmp_path / "pooled" / "zoo.md").read_text() == (tmp_path / "serial" / "zoo.md").read_text()


def _session_processes(sid: int) -> list[int]:
    """Processes of session ``sid`` (what the Ray head started: it does not leave its session)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


@pytest.fixture
def ray_head():
    """A Ray head of 2 CPUs on 127.0.0.1 in its own session: (address, the environment to join it
    with). Stopped afterwards, no process left."""
    pytest.importorskip("ray", reason="ray is in the test extra: pip install -e '.[test]'")
    # The head listens on every interface whatever its node address: a token of its own keeps
    # it to this test, and no token file in the home folder is read or written. Ray reads the
    # token when it is imported, hence a driver process of its own (ray_driver).
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
    address = f"127.0.0.1:{_free_port()}"
    # Ray's socket paths must stay short (AF_UNIX, 107 characters): not under pytest's tmp_path.
    temp_dir = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))
    log = temp_dir / "head.log"
    with log.open("w") as out:
        head = subprocess.Popen(
            [str(Path(sys.executable).parent / "ray"), "start", "--head", "--block", f"--port={address.split(':')[1]}",
             "--node-ip-address=127.0.0.1", "--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats",
             f"--temp-dir={temp_dir}"],
            stdout=out, stderr=subprocess.STDOUT, start_new_session=True, env=env)
    try:
        start = time.monotonic()
        # A driver that tries to join before the head is up stays unable to, so wait for the head's word.
        while "Ray runtime started" not in log.read_text():
            if head.poll() is not None or time.monotonic() - start > 180:
                pytest.fail(f"ray start did not start a head: {log.read_text()[-2000:]}")
            time.sleep(0.5)
        print(f"Ray head at {address} up in {time.monotonic() - start:.1f} s")
        yield address, env
    finally:
        # ray start --block stops its processes on SIGTERM, though not always all of them.
        os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(5)
        except subprocess.TimeoutExpired:
            pass
        for pid in _session_processes(head.pid):
            os.kill(pid, signal.SIGKILL)
        head.wait()
        deadline = time.monotonic() + 10
        while _session_processes(head.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        left = _session_processes(head.pid)
        shutil.rmtree(temp_dir, ignore_errors=True)
        assert not left, f"the Ray head left processes {left}"


# What the test runs on the head, in a driver process that joins it.
_RAY_DRIVER = """
import pickle, sys
from twin.sim.crosscheck import QUICK_GRID, run_zoo
from twin.tuning import tune_tracking_gains
address, out = sys.argv[1], sys.argv[2]
tuning = tune_tracking_gains(cluster=address, **{tuning!r})
_, zoo = run_zoo(out, configs=QUICK_GRID, robots={robots!r}, cluster=address)
with open(out + "/results.pickle", "wb") as f:
    pickle.dump((tuning, zoo), f)
"""


@pytest.mark.slow
def test_a_ray_head_gives_what_one_core_gives(ray_head, tmp_path):
    """A small tracking tuning and a QUICK_GRID zoo of two robots, through a Ray head on loopback."""
    address, env = ray_head
    options = {"evaluations": 3, "seeds": (0, 1), "steps": 40}
    out = tmp_path / "ray"
    out.mkdir()
    driver = subprocess.run([sys.executable, "-c", _RAY_DRIVER.format(tuning=options, robots=ZOO_ROBOTS), address,
                             str(out)], env=env, capture_output=True, text=True, timeout=600)
    assert driver.returncode == 0, driver.stderr[-3000:]
    on_ray, clustered = pickle.loads((out / "results.pickle").read_bytes())

    assert tune_tracking_gains(workers=1, **options) == on_ray
    _, serial = run_zoo(tmp_path / "serial", configs=QUICK_GRID, robots=ZOO_ROBOTS)
    assert clustered == serial and list(clustered) == ZOO_ROBOTS
    assert _zoo_csvs(out) == _zoo_csvs(tmp_path / "serial")


_LOCAL_LISTENERS = """
from twin import scaleout
ray = scaleout.connect("local", 1)
import psutil  # Ray's own copy, on the path once ray is imported
assert ray.get(ray.remote(lambda: 6 * 7).remote()) == 42
me = psutil.Process()
for process in [me] + me.children(recursive=True):
    for c in process.net_connections(kind="inet"):
        if c.status == psutil.CONN_LISTEN:
            print(process.name(), c.laddr.ip, c.laddr.port)
scaleout.disconnect()
"""


def test_cluster_local_listens_on_loopback_only():
    # Before: the local Ray instance's GCS, raylet and workers listened on all interfaces (::).
    pytest.importorskip("ray")
    result = subprocess.run([sys.executable, "-c", _LOCAL_LISTENERS], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    listeners = [line.split() for line in result.stdout.splitlines()]
    assert listeners and all(ip in ("127.0.0.1", "::ffff:127.0.0.1", "::1") for _, ip, _ in listeners), listeners
