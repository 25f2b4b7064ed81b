"""Rules of docs/architecture.md that a reviewer would otherwise check by eye: every function of the package is under
80 lines, library code (all but ``commands``) prints nothing (it returns or raises, and the command prints), and
nothing loads a file that can run code (pickle)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "vision_rl"
MAX_FUNCTION_LINES = 80


def long_functions(source: str, name: str) -> list[str]:
    """``name:line function (N lines)`` for each function of ``source`` of :data:`MAX_FUNCTION_LINES` lines or more."""
    return [
        f"{name}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.end_lineno - node.lineno + 1 >= MAX_FUNCTION_LINES
    ]


def print_calls(source: str, name: str) -> list[str]:
    """``name:line`` for each call of the builtin ``print`` in ``source`` (docstrings and comments are no calls)."""
    return [
        f"{name}:{node.lineno}"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print"
    ]


def code_loads(source: str, name: str) -> list[str]:
    """``name:line`` for each load that can run a file's code: ``pickle``/``cloudpickle``/``joblib`` loads,
    Stable-Baselines3's pickle readers, ``torch.load`` without ``weights_only=True``, and ``allow_pickle=True``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        owner = func.value.id if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) else None
        attr = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
        keywords = {k.arg: k.value for k in node.keywords}
        safe = isinstance(keywords.get("weights_only"), ast.Constant) and keywords["weights_only"].value is True
        pickled = isinstance(keywords.get("allow_pickle"), ast.Constant) and keywords["allow_pickle"].value is True
        if (
            (owner in ("pickle", "cloudpickle", "joblib") and attr in ("load", "loads"))
            or attr in ("load_from_pkl", "load_from_zip_file")
            or (owner == "torch" and attr == "load" and not safe)
            or pickled
        ):
            found.append(f"{name}:{node.lineno}")
    return found


def _package_files(skip: str | None = None) -> list[Path]:
    return [
        p for p in sorted(PACKAGE_DIR.rglob("*.py")) if skip is None or skip not in p.relative_to(PACKAGE_DIR).parts
    ]


def test_the_checks_find_a_long_function_and_a_print():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    assert long_functions(f"def f():\n{body}\n", "m.py") == [f"m.py:1 f ({MAX_FUNCTION_LINES + 1} lines)"]
    assert long_functions("def f():\n    return 1\n", "m.py") == []
    loads = "\n".join(
        [
            "torch.load(p)",
            "torch.load(p, weights_only=True)",
            "np.load(p, allow_pickle=True)",
            "pickle.loads(b)",
            "load_from_zip_file(p)",
        ]
    )
    assert code_loads(loads, "m.py") == ["m.py:1", "m.py:3", "m.py:4", "m.py:5"]
    assert print_calls('def f():\n    """print(1)"""\n    # print(2)\n    print(3)\n', "m.py") == ["m.py:4"]


def test_every_function_is_under_80_lines():
    found = [hit for path in _package_files() for hit in long_functions(path.read_text(), str(path.name))]
    assert not found, f"split these functions: {found}"


def test_library_code_prints_nothing():
    found = [
        hit
        for path in _package_files(skip="commands")
        for hit in print_calls(path.read_text(), str(path.relative_to(PACKAGE_DIR)))
    ]
    assert not found, f"library code returns or raises; the command prints: {found}"


def test_nothing_loads_a_file_that_can_run_code():
    found = [
        hit for path in _package_files() for hit in code_loads(path.read_text(), str(path.relative_to(PACKAGE_DIR)))
    ]
    assert not found, f"load tensors with weights_only=True and arrays without pickle: {found}"
