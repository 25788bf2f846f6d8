"""Where the twin's own files are, and where it keeps what it compiles.

Two layouts hold the same files. A checkout keeps ``models/`` and ``firmware/`` beside the
``twin`` package; an installed wheel ships them inside it, under ``twin/_shipped/`` (``setup.py``
copies them there). :func:`resource_path` is the one place that knows both; everything that
reads a model file or a firmware source goes through it.

What the twin compiles on first use (the plant loop, the host build of the firmware) and
Numba's compiled kernels go to a per-user cache, never into the package or the checkout, which
may be read-only: ``$TWIN_CACHE_DIR``, else ``$XDG_CACHE_HOME/twin``, else ``~/.cache/twin``.
A native library there is keyed by a hash of its sources, the compiler and its flags
(:func:`build_cached`), so a changed source or compiler builds anew and concurrent processes
(pytest-xdist workers) build it once. POSIX only: the builds use ``fcntl`` locks and ``.so``
libraries.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterable

__all__ = [
    "announce_kernel_compile",
    "NativeBuildError",
    "build_cached",
    "cache_dir",
    "find_compiler",
    "resource_path",
    "use_user_cache_for_numba",
]

_PACKAGE = Path(__file__).resolve().parent
# Directories shipped with the twin, and where each sits relative to the package in a wheel and
# in a checkout. The wheel's place comes first: beside an installed package is site-packages,
# where another distribution may have put a top-level ``models``. ``native`` is package data in
# both layouts.
_RESOURCES = {
    "models": (_PACKAGE / "_shipped" / "models", _PACKAGE.parent / "models"),
    "firmware": (_PACKAGE / "_shipped" / "firmware", _PACKAGE.parent / "firmware"),
    "native": (_PACKAGE / "sim" / "native",),
}


class NativeBuildError(RuntimeError):
    """A native part of the twin could not be built: no compiler, or the build failed."""


def resource_path(name: str) -> Path:
    """The directory of a shipped resource: ``models``, ``firmware`` or ``native`` (the plant
    loop's C++ source).

    Raises:
        KeyError: ``name`` is not one of the three.
        FileNotFoundError: the installation lacks it (a wheel built without ``setup.py``).
    """
    candidates = _RESOURCES[name]
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"the twin's {name}/ directory is missing (looked in {', '.join(map(str, candidates))}); "
                            "reinstall twin")


def cache_dir(*parts: str) -> Path:
    """The per-user cache directory of the twin (created), or a subdirectory of it.

    ``$TWIN_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/twin``, else ``~/.cache/twin``.
    """
    path = _cache_root().joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def _cache_root() -> Path:
    root = os.environ.get("TWIN_CACHE_DIR")
    if root:
        return Path(root)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return Path(xdg, "twin") if xdg else Path(os.path.expanduser("~"), ".cache", "twin")


def use_user_cache_for_numba() -> None:
    """Point Numba's on-disk cache at :func:`cache_dir` ``/numba`` unless ``NUMBA_CACHE_DIR``
    is set, so compiled kernels never land beside the installed sources.

    Called before any twin module imports numba (``twin/__init__.py``); numba reads the
    variable when it is first imported, and a numba imported earlier is pointed there too.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    path = str(_cache_root() / "numba")
    os.environ["NUMBA_CACHE_DIR"] = path
    config: Any = sys.modules.get("numba.core.config")  # numba ships no type information
    if config is not None and not config.CACHE_DIR:
        config.CACHE_DIR = path


def find_compiler(what: str) -> str:
    """The C++ compiler's path: ``$CXX`` if set, else ``g++`` on PATH.

    Args:
        what: what needs it, for the message (e.g. "the twin's plant loop").

    Raises:
        NativeBuildError: no such compiler; the message is one line saying what to install.
    """
    name = os.environ.get("CXX") or "g++"
    path = shutil.which(name)
    if path is None:
        raise NativeBuildError(f"{what} is compiled on first use and needs a C++ compiler, but {name!r} is not on "
                               "PATH: install g++ (e.g. apt install g++) or set CXX")
    return path


def build_cached(name: str, sources: Iterable[Path], key: Iterable[str], build: Callable[[Path, str], None],
                 *, what: str, error: type[NativeBuildError] = NativeBuildError, force: bool = False) -> Path:
    """The cached library ``name``, built by ``build`` if this cache has none for these inputs.

    The library lives at ``cache_dir("native", f"{stem}-{hash}")/name``, the hash taken over the
    sources' names and bytes, the compiler (:func:`find_compiler`) and its version, and ``key``
    (the flags...). Concurrent callers serialise on a lock file beside it; ``build`` writes into
    a fresh temporary directory, and the library is moved into place in one rename, so no
    process ever loads a half-written file.

    Args:
        name: the library's file name (``libtwinloop.so``).
        sources: every file the library is built from.
        key: further strings the build depends on.
        build: called with the temporary directory and the compiler's path; must leave ``name``
            in the directory, and raise :class:`NativeBuildError` when the build fails.
        what: what is built, for messages ("the twin's plant loop").
        error: the :class:`NativeBuildError` subclass to raise.
        force: build even if the cache has the library.

    Raises:
        NativeBuildError: (as ``error``) no compiler, or the build failed.
    """
    try:
        compiler = find_compiler(what)
        digest = hashlib.sha256()
        for source in sources:
            digest.update(source.name.encode() + b"\0" + source.read_bytes() + b"\0")
        for item in (compiler, _compiler_version(compiler), *key):
            digest.update(item.encode() + b"\0")
        folder = cache_dir("native", f"{name.split('.')[0]}-{digest.hexdigest()[:20]}")
        library = folder / name
        with open(folder / ".lock", "w") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                _say(f"waiting for another process compiling {what} into {folder}")
                fcntl.flock(lock, fcntl.LOCK_EX)
            if force or not library.exists():
                # Said, so a first run that sits at 0% is not taken for a hang.
                _say(f"compiling {what} with {Path(compiler).name} (once: its sources or the compiler are new "
                     f"to the cache {folder.parent}); later runs reuse it")
                start_s = time.monotonic()
                with tempfile.TemporaryDirectory(dir=folder, prefix=".build-") as tmp:
                    build(Path(tmp), compiler)
                    built = Path(tmp) / name
                    if not built.exists():
                        raise NativeBuildError(f"building {what} left no {name} in {tmp}")
                    os.replace(built, library)
                _say(f"compiled {what} in {time.monotonic() - start_s:.0f} s")
    except NativeBuildError as exc:
        if isinstance(exc, error):
            raise
        raise error(str(exc)) from None
    return library


def announce_kernel_compile(source: str, what: str) -> None:
    """Say at the terminal that ``what``'s Numba kernels, defined in the module file ``source``,
    compile on their first use in this process, when the on-disk cache holds none of them yet (a
    fresh install, or a cache cleared): that first use then takes tens of seconds of CPU with no
    other sign of life. The cache is where Numba keeps a module's kernels: its folder's name and
    a hash of its full path, below ``NUMBA_CACHE_DIR``."""
    cache = os.environ.get("NUMBA_CACHE_DIR")
    if not cache:
        return
    path = Path(source).resolve()
    folder = Path(cache, f"{path.parent.name}_{hashlib.sha1(str(path.parent).encode()).hexdigest()}")
    if not any(folder.glob(f"{path.stem}.*.nbi")):
        _say(f"compiling {what} (Numba, first use after install: 20-60 s of CPU, once; cached in {cache})")


def _say(line: str) -> None:
    """A progress line for the person at the terminal; not written into a captured stderr, where
    commands promise one line per error."""
    if sys.stderr is not None and sys.stderr.isatty():
        print(f"twin: {line}", file=sys.stderr, flush=True)


def _compiler_version(compiler: str) -> str:
    """``compiler --version``'s first line, part of a build's cache key."""
    try:
        result = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise NativeBuildError(f"{compiler} --version: {exc}") from None
    return result.stdout.partition("\n")[0]
