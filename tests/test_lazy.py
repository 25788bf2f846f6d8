"""Packages whose names load their module on first use (twin.lazy) export what they declare, and
the type checker's imports name the same things."""

import ast
import importlib
from pathlib import Path

import pytest

from twin.lazy import lazy_exports

ROOT = Path(__file__).resolve().parents[1]
LAZY = sorted(str(p.parent.relative_to(ROOT)).replace("/", ".") for p in (ROOT / "twin").glob("*/__init__.py")
              if "lazy_exports(" in p.read_text())


def test_the_packages_that_import_mujoco_or_numba_at_init_are_lazy():
    assert {"twin.control", "twin.device", "twin.discrepancy", "twin.force", "twin.rod", "twin.sim"} <= set(LAZY)


@pytest.mark.parametrize("package", LAZY)
def test_every_exported_name_resolves_to_its_module_and_the_type_checker_sees_the_same(package):
    module = importlib.import_module(package)
    exports = module._EXPORTS
    assert sorted(module.__all__) == sorted(exports)
    for name, source in exports.items():
        assert getattr(module, name) is getattr(importlib.import_module(source), name)
    tree = ast.parse((ROOT / package.replace(".", "/") / "__init__.py").read_text())
    checked = {(node.module, alias.name) for block in tree.body if isinstance(block, ast.If)
               for node in block.body if isinstance(node, ast.ImportFrom) for alias in node.names}
    assert checked == {(source, name) for name, source in exports.items()}


def test_an_unknown_name_is_an_attribute_error_naming_it():
    getattr_, dir_ = lazy_exports("twin", {"Params": "twin.params"})
    with pytest.raises(AttributeError, match="module 'twin' has no attribute 'Nope'"):
        getattr_("Nope")
    assert "Params" in dir_()
