"""The package's layering, read from the source: imports point only down the layers, no module imports in a cycle,
heavy dependencies stay in their layers, and importing the package or the simulator stays light."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "vision_rl"
PACKAGE = PACKAGE_DIR.name
#: Floors, lowest first; a module may import from its own layer and the floors below. The three papers' packages
#: share one floor and import nothing of each other. ``vision_rl/__init__.py`` sits below them all and imports only
#: gymnasium.
FLOORS = (
    ("files", "config", "budget", "signals"),
    ("sim",),
    ("render",),
    ("envs",),
    ("capture",),
    ("datasets",),
    ("phase1_repr",),
    ("evaluation",),
    ("training",),
    ("phase2_rl", "overtaking", "ddpg"),
    ("commands",),
)
#: The one exception to "the package root imports only gymnasium": ``vision_rl.evaluate``, the public door for agents
#: trained outside the project, which the root's module-level ``__getattr__`` imports from this module on first use
#: (so ``import vision_rl`` still loads gymnasium alone). Imported anywhere else in the root, or any other module of
#: the package imported there, breaks the rule; the lazy edge is left out of the layer and cycle checks.
ROOT_DOOR = "vision_rl.training.outside"
LAYERS = tuple(layer for floor in FLOORS for layer in floor)
PAPERS = FLOORS[-2]
#: Third-party packages kept out of some layers: name -> the layers that may import it.
HEAVY = {
    "torch": ("datasets", "phase1_repr", "evaluation", "training", *PAPERS, "commands"),
    "lightning": ("datasets", "phase1_repr", "training", *PAPERS, "commands"),
    "moderngl": ("render",),
    "optuna": ("phase2_rl",),
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _parse_imports(path: Path) -> tuple[set[tuple[str, tuple[str, ...]]], set[str]]:
    """(imports of the package as (module, names imported from it), top-level names of outside packages), from
    every import statement in the file, those inside functions included."""
    mod = module_name(path)
    own, outside = set(), set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == PACKAGE:
                    own.add((alias.name, ()))
                else:
                    outside.add(alias.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.split(".")[0] == PACKAGE:
                target = node.module
            else:
                outside.add((node.module or "").split(".")[0])
                continue
            own.add((target, tuple(alias.name for alias in node.names)))
    return own, outside


def import_graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(module -> the package's modules it imports, module -> outside packages it imports). ``from pkg import
    name`` counts as an import of the submodule ``pkg.name`` where one exists, else of ``pkg``."""
    parsed = {module_name(p): _parse_imports(p) for p in sorted(PACKAGE_DIR.rglob("*.py"))}
    known = set(parsed)
    graph: dict[str, set[str]] = {}
    for mod, (own, _) in parsed.items():
        deps = set()
        for target, names in own:
            subs = {f"{target}.{n}" for n in names if f"{target}.{n}" in known}
            deps |= subs if names and len(subs) == len(names) else subs | {target}
        graph[mod] = {d for d in deps if d in known and d != mod}
    return graph, {mod: outside for mod, (_, outside) in parsed.items()}


def without_the_door(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The import graph less the root's lazy import of :data:`ROOT_DOOR` (made only after the package is imported,
    from ``__getattr__``: neither a layer's import nor a cycle at import time)."""
    return {m: deps - {ROOT_DOOR} if m == PACKAGE else deps for m, deps in graph.items()}


def root_rule_violations(source: str) -> list[str]:
    """What the package root's ``source`` imports beyond gymnasium, except :data:`ROOT_DOOR` inside a module-level
    ``def __getattr__``: one line each."""
    tree = ast.parse(source)
    lazy = {
        id(node)
        for fn in tree.body
        if isinstance(fn, ast.FunctionDef) and fn.name == "__getattr__"
        for node in ast.walk(fn)
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [f"{PACKAGE}.{node.module}" if node.level and node.module else node.module or PACKAGE]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            door = name == ROOT_DOOR and id(node) in lazy
            if top not in {"gymnasium", "__future__"} and not door:
                where = "in __getattr__" if id(node) in lazy else f"line {node.lineno}"
                found.append(f"{name} ({where})")
    return found


def layer_of(module: str) -> str | None:
    """The module's layer: the package itself is ``""`` (the lowest), a module in no layer ``None``."""
    parts = module.split(".")
    if parts == [PACKAGE]:
        return ""
    return parts[1] if parts[1] in LAYERS else None


def rank(module: str) -> int:
    """The module's floor: -1 for the package root."""
    layer = layer_of(module)
    return -1 if layer == "" else next(k for k, floor in enumerate(FLOORS) if layer in floor)


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one module (an import cycle each)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def test_tarjan_finds_a_cycle_and_nothing_in_a_chain():
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_every_module_belongs_to_a_layer():
    graph, _ = import_graph()
    stray = {m: sorted(n for n, deps in graph.items() if m in deps) for m in graph if layer_of(m) is None}
    assert not stray, "modules in no layer (and who imports them): " + json.dumps(stray, indent=1)


def test_imports_point_down_the_layers():
    graph = without_the_door(import_graph()[0])
    upward = sorted(
        f"{m} ({layer_of(m) or 'package root'}) -> {d} ({layer_of(d)})"
        for m, deps in graph.items()
        for d in deps
        if layer_of(m) is not None and layer_of(d) is not None and rank(d) > rank(m)
    )
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_the_paper_packages_import_nothing_of_each_other():
    graph, _ = import_graph()
    sideways = sorted(
        f"{m} -> {d}"
        for m, deps in graph.items()
        for d in deps
        if layer_of(m) in PAPERS and layer_of(d) in PAPERS and layer_of(d) != layer_of(m)
    )
    assert not sideways, "imports between the papers' packages:\n" + "\n".join(sideways)


def test_no_import_cycles():
    graph = without_the_door(import_graph()[0])
    cycles = strongly_connected(graph)
    assert not cycles, "import cycles:\n" + "\n".join(", ".join(c) for c in cycles)


def test_the_package_root_imports_only_gymnasium():
    graph, outside = import_graph()
    assert graph[PACKAGE] <= {ROOT_DOOR}
    assert outside[PACKAGE] <= {"gymnasium", "__future__"}
    assert root_rule_violations((PACKAGE_DIR / "__init__.py").read_text(encoding="utf-8")) == []


def test_the_root_rule_allows_the_lazy_door_and_nothing_else():
    door = f"def __getattr__(name):\n    from {ROOT_DOOR} import evaluate\n    return evaluate\n"
    assert root_rule_violations("import gymnasium\n" + door) == []
    assert root_rule_violations(f"from {ROOT_DOOR} import evaluate\n") == [f"{ROOT_DOOR} (line 1)"]
    assert root_rule_violations(door.replace(ROOT_DOOR, "vision_rl.sim")) == ["vision_rl.sim (in __getattr__)"]
    assert root_rule_violations(door + "def load():\n    import numpy\n") == ["numpy (line 5)"]
    assert root_rule_violations(door.replace("evaluate\n", "evaluate\n    import torch\n", 1)) == [
        "torch (in __getattr__)"
    ]
    assert root_rule_violations("from .sim import world\n") == ["vision_rl.sim (line 1)"]


def test_heavy_dependencies_stay_in_their_layers():
    _, outside = import_graph()
    misplaced = sorted(
        f"{m} imports {dep}"
        for m, deps in outside.items()
        for dep in deps & set(HEAVY)
        if layer_of(m) not in HEAVY[dep]
    )
    assert not misplaced, "\n".join(misplaced)


def _modules_after(code: str) -> set[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    return set(json.loads(out.stdout.splitlines()[-1]))


@pytest.mark.slow
def test_import_vision_rl_registers_the_environments_and_loads_nothing_heavy():
    probe = (
        "import vision_rl, gymnasium\nassert 'vision_rl/TimeTrial-v1' in gymnasium.registry\n"
        "assert 'vision_rl/Overtaking-v1' in gymnasium.registry"
    )
    loaded = _modules_after(probe)
    assert not {"torch", "moderngl", "vision_rl.envs", "vision_rl.training"} & loaded
    assert not {"torch", "moderngl", "vision_rl.commands"} & _modules_after("import vision_rl.sim")


@pytest.mark.slow
def test_gymnasium_make_works_after_import_vision_rl():
    probe = (
        "import vision_rl, gymnasium\nenv = gymnasium.make('vision_rl/TimeTrial-v1', track='technical')\n"
        "obs, _ = env.reset(seed=0)\nassert obs.shape == (38,)"
    )
    _modules_after(probe)
