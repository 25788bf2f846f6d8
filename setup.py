"""Packaging: everything is declared in pyproject.toml but one step, done here.

A wheel must carry ``models/`` (the parameter file the twin loads) and ``firmware/`` (the C++ the
emulated board is built from on first use), which live beside the ``twin`` package in the
checkout. ``build_py`` copies them into the built package as ``twin/_shipped/models`` and
``twin/_shipped/firmware``, where :func:`twin.resources.resource_path` finds them. An editable
install needs no copy: there ``resource_path`` finds the checkout's own folders.

``envs/`` (the Gymnasium envs) sits at the top of the checkout but installs as ``twin.envs``
(``package_dir``), so nothing named ``envs``, an unrelated PyPI package, lands in site-packages;
an editable install maps ``twin.envs`` to the checkout's ``envs/`` the same way.
"""

from pathlib import Path

from setuptools import find_namespace_packages, setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
SHIPPED = ("models", "firmware")
# What is made from the sources, in the checkout, never shipped.
_SKIP_DIRS = {"build", "__pycache__"}
_SKIP_SUFFIXES = {".so", ".o", ".pyc", ".elf"}


def _shipped_files(folder: Path):
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder)
        if path.is_file() and not _SKIP_DIRS.intersection(relative.parts[:-1]) and path.suffix not in _SKIP_SUFFIXES:
            yield relative


class BuildPyWithResources(build_py):
    """``build_py`` that also copies the shipped folders into ``twin/_shipped/``."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        for name in SHIPPED:
            for relative in _shipped_files(HERE / name):
                target = Path(self.build_lib, "twin", "_shipped", name, relative)
                self.mkpath(str(target.parent))
                self.copy_file(str(HERE / name / relative), str(target))


setup(
    packages=find_namespace_packages(include=["twin", "twin.*"]) + ["twin.envs"],
    package_dir={"twin.envs": "envs"},
    cmdclass={"build_py": BuildPyWithResources},
)
