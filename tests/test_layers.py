"""The package layers: ur5kin -> regions -> envs -> ddpg_her -> analysis, no import cycle, and
the modules that read a task or a region load neither Pinocchio nor torch.

The import graph is read from the source (``ast``), so a cycle fails here before it fails at
import time in some order only.
"""

from __future__ import annotations

import ast
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAYERS = ("ur5kin", "regions", "envs", "ddpg_her", "analysis")
"""Lowest first: a package may import only packages before it."""

LIGHT_MODULES = ("ur5kin.world", "ur5kin.checks", "regions.shapes", "regions.registry",
                 "regions.samplers", "envs.spec", "envs.gains")
"""Modules that import neither Pinocchio nor torch (reading a task or a region needs no
physics)."""


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for package in LAYERS:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The project module ``name`` refers to (a module or its package), None if external."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _is_type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imports(path: pathlib.Path, module: str, top_level_only: bool,
             type_checking: bool = False) -> set[str]:
    """Project modules imported by ``path``: at import time only, or anywhere (and in
    ``if TYPE_CHECKING:`` blocks too when ``type_checking``)."""
    tree = ast.parse(path.read_text())
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if _is_type_checking(child) and not type_checking:
                continue
            if top_level_only and isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef
                                             | ast.Lambda):
                continue
            if isinstance(child, ast.Import):
                names = [alias.name for alias in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    parent = module if path.stem == "__init__" else module.rpartition(".")[0]
                    for _ in range(child.level - 1):
                        parent = parent.rpartition(".")[0]
                    base = ".".join(filter(None, [parent, base]))
                names = [f"{base}.{alias.name}" for alias in child.names] + [base]
            else:
                visit(child)
                continue
            for name in names:
                target = _resolve(name)
                if target is not None and target != module:
                    found.add(target)

    visit(tree)
    return found


def test_no_import_cycle_even_through_lazy_imports():
    # an import inside a function or for type checking hides a cycle from the interpreter,
    # not from the design (envs.spec <-> envs.physics.pinocchio_loop was one)
    graph = {m: _imports(p, m, top_level_only=False, type_checking=True)
             for m, p in MODULES.items()}
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    cycles = []

    def dfs(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*stack[stack.index(nxt):], nxt]))
            elif nxt not in state:
                dfs(nxt, [*stack, nxt])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            dfs(module, [module])
    assert not cycles, f"import cycles: {cycles}"


def test_no_package_imports_a_later_layer_even_lazily():
    upward = [f"{m} imports {t}"
              for m, p in MODULES.items() for t in _imports(p, m, top_level_only=False)
              if LAYERS.index(t.partition(".")[0]) > LAYERS.index(m.partition(".")[0])]
    assert not upward, upward


def test_the_arm_geometry_belongs_to_ur5kin_and_the_physics_ignores_the_goal_layer():
    for module, path in MODULES.items():
        if module.startswith("regions"):
            assert "ur5kin.collision" not in _imports(path, module, top_level_only=False), module
            source = path.read_text()
            for name in ("def link_heights", "def collision_geometry", "class Capsule"):
                assert name not in source, f"{module} defines {name}"
    for module in (m for m in MODULES if m.startswith("envs.physics")):
        dynamics = _imports(MODULES[module], module, top_level_only=False)
        assert not any(t.startswith("regions") for t in dynamics), (module, dynamics)


@pytest.mark.parametrize("module", LIGHT_MODULES)
def test_reading_modules_load_neither_pinocchio_nor_torch(module):
    code = (f"import sys, {module}\n"
            "print(sorted(m for m in ('pinocchio', 'torch') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout
    assert out.strip() == "[]", f"import {module} loaded {out.strip()}"


@pytest.mark.parametrize("package", ["ur5kin", "regions", "envs"])
def test_lazy_exports_stay_the_exported_objects_once_every_submodule_is_loaded(package):
    # a submodule loaded by the import system must not shadow an exported name (ur5kin.ik)
    import importlib
    import types

    pkg = importlib.import_module(package)
    for module in MODULES:
        if module.startswith(package + "."):
            importlib.import_module(module)
    for name in pkg.__all__:
        assert not isinstance(getattr(pkg, name), types.ModuleType), f"{package}.{name}"


ENVS_FLOORS = 6
"""Most floors of envs' import graph (issue 27): a module stands one floor above everything in
envs it imports, anywhere in it (in functions and for type checking too)."""


def test_envs_stands_on_at_most_six_floors():
    graph = {m: {t for t in _imports(p, m, top_level_only=False, type_checking=True)
                 if t.startswith("envs.") or t == "envs"}
             for m, p in MODULES.items() if m.startswith("envs.")}
    floor: dict[str, int] = {}

    def height(module: str) -> int:
        if module not in floor:
            floor[module] = 1 + max((height(t) for t in graph.get(module, ()) if t != "envs"),
                                    default=0)
        return floor[module]

    tops = {m: height(m) for m in graph}
    assert max(tops.values()) <= ENVS_FLOORS, sorted(tops.items(), key=lambda kv: -kv[1])


def test_no_module_imports_a_private_name_of_another_module():
    private = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                private += [f"{module}: from {node.module} import {a.name}" for a in node.names
                            if a.name.startswith("_") and not a.name.startswith("__")]
    assert not private, private

