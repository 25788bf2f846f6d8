"""A real install: the wheel in a fresh virtual environment, used from outside the checkout.

The fast tests pin down the pieces (where resources are found, the per-user build cache and its
lock); the slow ones build the wheel, install it with its dependencies from the package index
(once at the latest versions, once at pyproject's lower bounds) and run the commands a user runs.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import pytest
from packaging.version import Version

from twin.resources import NativeBuildError, build_cached, cache_dir, resource_path

ROOT = Path(__file__).resolve().parents[1]
TENSIONS = "2.5,1.35,1.35,1.35"


# --- where things are ----------------------------------------------------------------------------

def test_a_checkout_finds_its_own_models_firmware_and_native_source():
    assert resource_path("models") == ROOT / "models"
    assert resource_path("firmware") == ROOT / "firmware"
    assert (resource_path("native") / "loop.cpp").is_file()
    with pytest.raises(KeyError):
        resource_path("nothing")


def test_cache_dir_follows_twin_cache_dir_then_xdg_then_home(tmp_path, monkeypatch):
    monkeypatch.delenv("TWIN_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir("native") == tmp_path / "xdg" / "twin" / "native"
    assert (tmp_path / "xdg" / "twin" / "native").is_dir()
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "twin"
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_dir("x") == tmp_path / "mine" / "x"


def test_numba_cache_goes_to_the_user_cache_unless_set():
    code = "import os, twin, numba.core.config as c; print(os.environ['NUMBA_CACHE_DIR']); print(c.CACHE_DIR)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["TWIN_CACHE_DIR"] = "/nonexistent/twin-cache"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["/nonexistent/twin-cache/numba"] * 2
    env["NUMBA_CACHE_DIR"] = "/elsewhere"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["/elsewhere"] * 2


# --- the build cache -----------------------------------------------------------------------------

def _fake_build(log: Path):
    """A build that takes a while and appends to ``log`` each time it runs."""
    def build(folder: Path, compiler: str) -> None:
        with open(log, "a") as fh:
            fh.write(f"{os.getpid()}\n")
        time.sleep(0.5)
        (folder / "libfake.so").write_text(compiler)
    return build


def _build_in_process(args) -> str:
    cache, source, log = args
    os.environ["TWIN_CACHE_DIR"] = cache
    return str(build_cached("libfake.so", [Path(source)], ["-O2"], _fake_build(Path(log)), what="a fake library"))


def test_two_processes_building_at_once_build_once(tmp_path):
    source = tmp_path / "fake.cpp"
    source.write_text("int f() { return 1; }\n")
    log = tmp_path / "builds.log"
    args = (str(tmp_path / "cache"), str(source), str(log))
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        paths = pool.map(_build_in_process, [args, args])
    assert paths[0] == paths[1]
    assert len(log.read_text().split()) == 1
    library = Path(paths[0])
    assert library.is_file() and library.parent.parent == tmp_path / "cache" / "native"
    assert [p.name for p in library.parent.iterdir() if p.name.startswith(".build-")] == []


def test_a_changed_source_or_flag_builds_anew_and_the_same_inputs_do_not(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "cache"))
    source = tmp_path / "fake.cpp"
    source.write_text("int f() { return 1; }\n")
    log = tmp_path / "builds.log"
    first = build_cached("libfake.so", [source], ["-O2"], _fake_build(log), what="a fake library")
    assert build_cached("libfake.so", [source], ["-O2"], _fake_build(log), what="a fake library") == first
    other_flags = build_cached("libfake.so", [source], ["-O3"], _fake_build(log), what="a fake library")
    source.write_text("int f() { return 2; }\n")
    other_source = build_cached("libfake.so", [source], ["-O2"], _fake_build(log), what="a fake library")
    assert len({first, other_flags, other_source}) == 3
    assert len(log.read_text().split()) == 3


def test_no_compiler_is_one_line_naming_what_to_install(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", "no-such-compiler-g++")
    source = tmp_path / "fake.cpp"
    source.write_text("\n")

    class FakeError(NativeBuildError):
        pass

    with pytest.raises(FakeError) as caught:
        build_cached("libfake.so", [source], [], _fake_build(tmp_path / "log"), what="a fake library", error=FakeError)
    message = str(caught.value)
    assert "\n" not in message
    assert "a fake library" in message and "no-such-compiler-g++" in message and "install g++" in message
    assert not (tmp_path / "log").exists()


def test_a_failed_build_leaves_nothing_in_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "cache"))
    source = tmp_path / "fake.cpp"
    source.write_text("\n")

    def broken(folder: Path, compiler: str) -> None:
        (folder / "libfake.so").write_text("half")
        raise NativeBuildError("the compiler said no")

    with pytest.raises(NativeBuildError, match="the compiler said no"):
        build_cached("libfake.so", [source], [], broken, what="a fake library")
    assert list((tmp_path / "cache" / "native").rglob("libfake.so")) == []


# --- the wheel, installed --------------------------------------------------------------------------

def _lower_bounds() -> dict[str, str]:
    """pyproject's runtime dependencies as name → lower bound."""
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    bounds = {}
    for dep in deps:
        match = re.fullmatch(r"([A-Za-z0-9_.-]+)>=([0-9][0-9.]*)", dep.replace(" ", ""))
        assert match, f"{dep!r}: every dependency needs a lower bound (name>=version) that is tested"
        bounds[match[1]] = match[2]
    return bounds


def test_every_dependency_has_a_lower_bound():
    bounds = _lower_bounds()
    assert {"numpy", "mujoco", "numba", "mcap", "mcap-ros2-support"} <= set(bounds)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the checkout's files (a build in the checkout would leave
    build/ behind, and another engineer's untracked files could slip in)."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout to know the source files")
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                           capture_output=True, check=True).stdout.decode().split("\0")
    base = tmp_path_factory.mktemp("wheel")
    source = base / "src"
    for name in filter(None, files):
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(base / "dist"), str(source)],
                   check=True, capture_output=True, text=True)
    (built,) = (base / "dist").glob("twin-*.whl")
    return built


def _install(wheel: Path, folder: Path, constraints: dict[str, str] | None = None) -> Path:
    """A fresh venv (no system site-packages) with the wheel and its dependencies; its bin/."""
    subprocess.run([sys.executable, "-m", "venv", str(folder)], check=True)
    command = [str(folder / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check",
               "--no-compile", str(wheel)]
    if constraints:
        pins = folder / "constraints.txt"
        pins.write_text("".join(f"{name}=={version}\n" for name, version in constraints.items()))
        command += ["-c", str(pins)]
    result = subprocess.run(command, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-4000:]
    return folder / "bin"


def _env(cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "NUMBA_CACHE_DIR", "TWIN_CACHE_DIR", "CXX")}
    env["TWIN_CACHE_DIR"] = str(cache)
    return env


def _run(bin_dir: Path, args: list[str], cwd: Path, env: dict[str, str], timeout_s: float = 600):
    return subprocess.run([str(bin_dir / "twin"), *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout_s)


def _smoke(bin_dir: Path, work: Path) -> None:
    """predict, sim, emulate (briefly) and validate --quick, run from ``work`` (outside the checkout)."""
    from twin import load_params
    from twin.pose import HORIZONTAL
    from twin.rod import RodModel, solve

    work.mkdir()
    env = _env(work / "cache")
    where = subprocess.run([str(bin_dir / "python"), "-c", "import twin, twin.resources as r; print(twin.__file__); "
                            "print(r.resource_path('models')); print(r.resource_path('firmware'))"],
                           cwd=work, env=env, capture_output=True, text=True, check=True).stdout.split("\n")
    site = Path(where[0]).parent
    assert ROOT not in site.parents, f"the installed twin is imported from the checkout ({site})"
    assert [Path(p) for p in where[1:3]] == [site / "_shipped" / "models", site / "_shipped" / "firmware"]

    result = _run(bin_dir, ["predict", "--tensions", TENSIONS, "--tip-force", "0,0,-0.049", "--pose", "horizontal",
                            "--json"], work, env)
    assert result.returncode == 0, result.stderr[-4000:]
    installed = json.loads(result.stdout)
    here = solve(RodModel.from_params(load_params()), [2.5, 1.35, 1.35, 1.35], tip_force_n=[0, 0, -0.049],
                 base_rotation=HORIZONTAL)
    assert installed["converged"]
    assert installed["tip_position_m"] == pytest.approx(here.tip_position_m.tolist(), abs=1e-9)

    result = _run(bin_dir, ["sim", "--tensions", TENSIONS], work, env)
    assert result.returncode == 0, result.stderr[-4000:]
    assert "settled: True" in result.stdout

    board = subprocess.Popen([str(bin_dir / "twin"), "emulate"], cwd=work, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    # A board that never prints its port would block readline: kill it after a generous while.
    watchdog = threading.Timer(300, board.kill)
    watchdog.start()
    try:
        lines = [board.stdout.readline() for _ in range(2)]
        assert lines[0].startswith("port: /dev/") and lines[1].startswith("url:  serial:///dev/"), lines
        time.sleep(1.0)
        board.send_signal(signal.SIGTERM)
        out, err = board.communicate(timeout=60)
    finally:
        watchdog.cancel()
        if board.poll() is None:
            board.kill()
            board.wait()
    assert board.returncode == 0, err[-4000:]
    ticks = int(re.search(r"stopped after (\d+) ticks", out)[1])
    assert ticks > 0

    result = _run(bin_dir, ["validate", "--quick"], work, env)
    assert result.returncode == 0, result.stderr[-4000:]
    (run,) = (work / "runs").glob("validate-*")
    summary = json.loads((run / "summary.json").read_text())
    assert (run / "report.md").is_file()
    assert summary["rows"] == 24 and summary["failed_predictions"] == 0
    assert summary["worst_error_mm"] < 1.0

    # The run's dataset as a ROS 2 bag, read back here.
    result = _run(bin_dir, ["export-bag", str(run), "sweep.mcap"], work, env)
    assert result.returncode == 0, result.stderr[-4000:]
    from mcap.reader import make_reader
    with open(work / "sweep.mcap", "rb") as stream:
        counts = make_reader(stream).get_summary().statistics.channel_message_counts
    # /tf_static once; tendons, measured tip, predicted tip, backbone and estimated tip wrench per row
    # (every prediction converged).
    assert sorted(counts.values()) == [1, 24, 24, 24, 24, 24]

    # The Gymnasium envs come as twin.envs, registered on import; no top-level `envs` exists.
    gym_check = subprocess.run([str(bin_dir / "python"), "-c", "import importlib.util, gymnasium as gym, twin.envs; "
                                "assert importlib.util.find_spec('envs') is None; "
                                "print(gym.make('twin/EndoscopeReach-v0').unwrapped.__module__)"],
                               cwd=work, env=env, capture_output=True, text=True)
    assert gym_check.returncode == 0, gym_check.stderr[-4000:]
    assert gym_check.stdout.split() == ["twin.envs.reach"]

    # Another robot of the zoo ships too.
    result = _run(bin_dir, ["predict", "--robot", "three-tendon", "--tensions", "2,1,1", "--json"], work, env)
    assert result.returncode == 0, result.stderr[-4000:]
    assert json.loads(result.stdout)["converged"]

    # Native parts went to the cache, nothing into the installed package.
    assert len(list((work / "cache" / "native").glob("libtwinloop-*/libtwinloop.so"))) == 1
    assert len(list((work / "cache" / "native").glob("libtwinfw-*/libtwinfw.so"))) == 1
    assert list((work / "cache" / "numba").rglob("*.nbi"))
    built_in_package = [p for p in site.rglob("*") if p.suffix in (".so", ".nbi", ".nbc") or p.name == "build"]
    assert built_in_package == []

    # Without a compiler (and an empty build cache): the predictor runs, the twin says in one
    # line what to install, no traceback.
    env_no_cxx = dict(env, CXX="no-such-compiler-g++", TWIN_CACHE_DIR=str(work / "empty-cache"),
                      NUMBA_CACHE_DIR=str(work / "cache" / "numba"))
    result = _run(bin_dir, ["predict", "--tensions", TENSIONS], work, env_no_cxx)
    assert result.returncode == 0, result.stderr[-4000:]
    result = _run(bin_dir, ["sim", "--tensions", TENSIONS], work, env_no_cxx)
    assert result.returncode == 1
    assert result.stderr.strip().count("\n") == 0 and "needs a C++ compiler" in result.stderr, result.stderr


@pytest.mark.slow
def test_the_wheel_puts_envs_under_twin_and_nothing_at_the_top(wheel):
    import zipfile
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert top == {"twin"}, top
    assert {"twin/envs/__init__.py", "twin/envs/reach.py", "twin/envs/randomization.py"} <= set(names)


@pytest.mark.slow
def test_the_wheel_installs_and_runs_outside_the_checkout(wheel, tmp_path):
    bin_dir = _install(wheel, tmp_path / "venv")
    _smoke(bin_dir, tmp_path / "work")


@pytest.mark.slow
def test_the_lower_bounds_of_the_dependencies_are_real(wheel, tmp_path):
    bin_dir = _install(wheel, tmp_path / "venv", constraints=_lower_bounds())
    versions = json.loads(subprocess.run(
        [str(bin_dir / "python"), "-c", "import json, importlib.metadata as m, sys; "
         "print(json.dumps({n: m.version(n) for n in sys.argv[1:]}))", *_lower_bounds()],
        capture_output=True, text=True, check=True).stdout)
    assert {n: Version(v) for n, v in versions.items()} == {n: Version(v) for n, v in _lower_bounds().items()}
    _smoke(bin_dir, tmp_path / "work")


def test_the_first_kernel_compile_is_announced_only_while_the_cache_holds_none(tmp_path, monkeypatch):
    from twin import resources
    from twin.rod import kernel

    said = []
    monkeypatch.setattr(resources, "_say", said.append)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    resources.announce_kernel_compile(kernel.__file__, "the predictor's kernels")
    assert len(said) == 1 and "compiling the predictor's kernels" in said[0] and str(tmp_path) in said[0]
    # Numba's own cache files for the module, where Numba writes them, silence it.
    import numba.core.caching as caching

    folder = tmp_path / caching._CacheLocator.get_suitable_cache_subpath(kernel.__file__)
    folder.mkdir()
    (folder / "kernel.integrate-1.py311.nbi").write_bytes(b"")
    resources.announce_kernel_compile(kernel.__file__, "the predictor's kernels")
    assert len(said) == 1
