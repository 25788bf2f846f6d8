"""The packages form layers that only point down: no import cycle between them.

Every import under ``twin/`` and ``envs/`` counts, including relative imports and imports inside
functions (a lazy import is still a dependency). Each subpackage of ``twin`` is one node
(``twin.driver``, ``twin.device``, ``twin.data``, ...), each top-level module of ``twin`` is its own node
(``twin.params``, ``twin.tuning``, ...), and ``envs/``, installed as ``twin.envs``, is one node.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Folder of the checkout → the package it installs as (setup.py's package_dir).
PACKAGES = {"twin": "twin", "envs": "twin.envs"}


def _module_name(path: Path) -> str:
    folder, *parts = path.relative_to(ROOT).with_suffix("").parts
    if parts and parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGES[folder], *parts])


def _modules() -> dict[str, Path]:
    return {_module_name(path): path for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))}


def _node(module: str) -> str | None:
    """The layer ``module`` belongs to, or None outside the project."""
    parts = module.split(".")
    if parts[0] != "twin":
        return None
    if len(parts) == 1:
        return "twin"
    return "twin." + parts[1]


def _imported_modules(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            # ``from twin import effects`` imports the module twin.effects, not only twin.
            submodules = {f"{target}.{alias.name}" for alias in node.names} & modules.keys()
            found.update(submodules or {target})
    return found


def import_graph() -> dict[str, dict[str, list[str]]]:
    """Layer → layer it imports → the importing modules (for the failure message)."""
    modules = _modules()
    graph: dict[str, dict[str, list[str]]] = {}
    for name, path in modules.items():
        source = _node(name)
        edges = graph.setdefault(source, {})
        for imported in _imported_modules(name, path, modules):
            target = _node(imported)
            if target is not None and target != source:
                edges.setdefault(target, []).append(name)
    return graph


def find_cycle(graph: dict[str, dict[str, list[str]]]) -> list[str] | None:
    """One cycle of the graph as a closed path [a, b, ..., a], or None."""
    state: dict[str, str] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = "open"
        stack.append(node)
        for target in sorted(graph.get(node, {})):
            if state.get(target) == "open":
                return stack[stack.index(target):] + [target]
            if target not in state:
                cycle = visit(target)
                if cycle:
                    return cycle
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_no_import_cycle_between_packages():
    graph = import_graph()
    cycle = find_cycle(graph)
    if cycle:
        steps = [f"{a} -> {b} (in {', '.join(sorted(set(graph[a][b])))})" for a, b in zip(cycle, cycle[1:])]
        pytest.fail("import cycle between packages: " + " -> ".join(cycle) + "\n  " + "\n  ".join(steps))


# Layers that must not import each other in this direction (lower → higher).
_MUST_NOT_IMPORT = {
    "twin.data": ("twin.experiments", "twin.discrepancy", "twin.control", "twin.tuning", "twin.envs"),
    "twin.experiments": ("twin.discrepancy", "twin.control", "twin.tuning", "twin.envs"),
    "twin.discrepancy": ("twin.control", "twin.tuning", "twin.envs"),
    "twin.control": ("twin.tuning", "twin.envs"),
    "twin.envs": ("twin.tuning",),
    "twin.device": ("twin.data", "twin.experiments", "twin.discrepancy", "twin.control", "twin.tuning", "twin.envs"),
    # The rig driver sits below the twin: the emulated board, sim:// and the twin server are
    # above it (twin.device), the simulation further up still (twin.sim, twin.rod).
    "twin.driver": ("twin.device", "twin.sim", "twin.rod", "twin.data", "twin.experiments", "twin.discrepancy",
                    "twin.control", "twin.tuning", "twin.envs"),
}


@pytest.mark.parametrize("lower", sorted(_MUST_NOT_IMPORT))
def test_lower_layers_do_not_import_higher_ones(lower):
    graph = import_graph()
    assert lower in graph, f"{lower} has no modules"
    upward = {target: graph[lower][target] for target in _MUST_NOT_IMPORT[lower] if target in graph[lower]}
    assert not upward, f"{lower} imports layers above it: {upward}"


def test_the_graph_sees_relative_and_function_level_imports(tmp_path, monkeypatch):
    """The parser maps what a cycle hides in: a relative import and an import inside a function."""
    for package in ("twin/low", "twin/high", "envs"):
        (tmp_path / package).mkdir(parents=True)
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "twin" / "__init__.py").write_text("")
    (tmp_path / "twin" / "low" / "a.py").write_text("def f():\n    from twin.high import b\n")
    (tmp_path / "twin" / "high" / "b.py").write_text("from ..low import a\n")
    (tmp_path / "twin" / "high" / "c.py").write_text("from twin import params\n")
    (tmp_path / "twin" / "params.py").write_text("")
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    graph = import_graph()
    assert set(graph["twin.low"]) == {"twin.high"}
    assert set(graph["twin.high"]) == {"twin.low", "twin.params"}
    assert find_cycle(graph) in (["twin.high", "twin.low", "twin.high"], ["twin.low", "twin.high", "twin.low"])


def _reachable(graph: dict[str, dict[str, list[str]]], start: str) -> dict[str, list[str]]:
    """Every layer ``start`` reaches through imports (lazy ones too) → the path that reaches it."""
    paths = {start: [start]}
    todo = [start]
    while todo:
        node = todo.pop()
        for target in sorted(graph.get(node, {})):
            if target not in paths:
                paths[target] = paths[node] + [target]
                todo.append(target)
    return paths


def test_the_driver_reaches_no_twin_through_any_import():
    """Not only its own imports: no module the driver imports, however indirectly or lazily,
    imports the twin's rooms (so a host on the rig can never be made to load them)."""
    paths = _reachable(import_graph(), "twin.driver")
    assert "twin.tracking" in paths, "the graph lost the driver's tracker client"
    found = {node: " -> ".join(path) for node, path in paths.items()
             if node in ("twin.device", "twin.sim", "twin.rod", "twin.envs")}
    assert not found, f"twin.driver reaches the twin: {found}"


# What importing the driver and opening a board over the network may not load.
_NOT_ON_THE_RIG = ("mujoco", "numba", "llvmlite", "scipy", "gymnasium", "twin.sim", "twin.rod", "twin.device")


def test_importing_the_driver_and_opening_a_network_board_loads_no_twin():
    """The driver in a fresh interpreter: import it, list its schemes (the twin's ``sim://``
    among them, found by name) and build a ``socket://`` device; nothing of the twin, MuJoCo,
    Numba or SciPy is loaded."""
    code = textwrap.dedent("""
        import json, sys
        import twin.driver
        from twin.driver import open_device, schemes
        before = sorted(m for m in sys.modules if m.startswith(tuple(sys.argv[1].split(","))))
        names = sorted(schemes())
        device = open_device("socket://127.0.0.1:9?igtl=127.0.0.1:18944&pose=up")
        loaded = sorted(m for m in sys.modules if m.startswith(tuple(sys.argv[1].split(","))))
        print(json.dumps({"before": before, "schemes": names, "loaded": loaded, "url": device.url}))
    """)
    run = subprocess.run([sys.executable, "-c", code, ",".join(_NOT_ON_THE_RIG)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["before"] == []
    assert {"serial", "socket", "rfc2217", "sim"} <= set(out["schemes"])
    # Listing sim:// imports its registering module, but not the board, the plant or MuJoCo.
    assert "twin.device.sim_url" in out["loaded"]
    assert all(m.startswith("twin.device") for m in out["loaded"]), out["loaded"]
    assert not {"twin.device.board", "twin.device.firmware_lib", "twin.device.sim_transport"} & set(out["loaded"])
    assert out["url"].startswith("socket://127.0.0.1:9")


# The device layer's own parts: what is above it reaches the twin through device.twin.
_DEVICE_INTERNALS = ("twin.device.board", "twin.device.sim_transport", "twin.device.firmware_lib")


def _seam_violations(path: Path, *, check_imports: bool) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute):
            pair = (node.value.attr, node.attr)
            # device.transport.<anything>, <board>.plant, <fixture or twin>._board
            if pair[0] == "transport" or pair == ("board", "plant") or node.attr == "_board":
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: .{pair[0]}.{pair[1]}")
        elif check_imports and isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            found += [f"{path.relative_to(ROOT)}:{node.lineno}: imports {n}" for n in names
                      if n.startswith(_DEVICE_INTERNALS)]
    return found


def test_nothing_above_the_device_reaches_through_its_seam():
    """The env, the experiments and the tests read and reset the twin through ``device.twin``, never
    through the transport, the emulated board or its plant; only the device and the twin import the
    board's parts (tests of those parts may import them too)."""
    above = [p for package in PACKAGES for p in sorted((ROOT / package).rglob("*.py"))
             if not p.is_relative_to(ROOT / "twin" / "device") and not p.is_relative_to(ROOT / "twin" / "sim")]
    found = [v for p in above for v in _seam_violations(p, check_imports=True)]
    found += [v for p in sorted((ROOT / "tests").rglob("*.py")) for v in _seam_violations(p, check_imports=False)]
    assert not found, "reaches through the device seam:\n  " + "\n  ".join(found)


def test_nothing_imports_a_top_level_envs():
    """``envs/`` installs as ``twin.envs``: a top-level ``import envs`` works in the checkout only, and
    in an installed twin would find the unrelated PyPI package of that name (or nothing)."""
    modules = _modules()
    assert "twin.envs.reach" in modules
    found = sorted(f"{name} imports {imported}" for name, path in modules.items()
                   for imported in _imported_modules(name, path, modules) if imported.split(".")[0] == "envs")
    found += sorted(f"{path.relative_to(ROOT)} imports {imported}" for path in sorted((ROOT / "tests").rglob("*.py"))
                    for imported in _imported_modules("tests." + path.stem, path, modules)
                    if imported.split(".")[0] == "envs")
    assert not found, "\n  ".join(["top-level envs imported:", *found])
