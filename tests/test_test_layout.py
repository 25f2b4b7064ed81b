"""The test suite's layout, read from its source: a test module or conftest imports nothing of the suite but
tests.helpers, every folder under tests/ tests one package of vision_rl (besides helpers/ and faults/), and every
folder is a package, so that two folders' test modules of one name never collide."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

TESTS_DIR = Path(__file__).resolve().parent
PACKAGE_DIR = TESTS_DIR.parent / "vision_rl"
HELPERS = "tests.helpers"
#: Folders under tests/ that mirror no package: the helpers the suite shares and the fault-injection suite.
UNMIRRORED = ("helpers", "faults")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(TESTS_DIR.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def suite_imports(source: str, module: str, is_package: bool = False) -> list[str]:
    """The suite's modules (``tests...``) that ``source``, the module ``module``, imports, sorted: every import
    statement, those inside functions included, relative ones resolved; ``from tests import x`` is ``tests.x``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found += [f"{target}.{alias.name}" for alias in node.names] if target == "tests" else [target]
    return sorted(name for name in found if name == "tests" or name.startswith("tests."))


def foreign_imports(source: str, module: str, is_package: bool = False) -> list[str]:
    """The suite's modules that ``source`` imports other than tests.helpers and its modules."""
    return [
        name
        for name in suite_imports(source, module, is_package)
        if name != HELPERS and not name.startswith(HELPERS + ".")
    ]


def python_files(tests_dir: Path) -> list[Path]:
    return sorted(p for p in tests_dir.rglob("*.py") if "__pycache__" not in p.parts)


def folders(tests_dir: Path) -> list[Path]:
    """Every folder under ``tests_dir``, caches and hidden folders left out."""
    return sorted(
        p
        for p in tests_dir.rglob("*")
        if p.is_dir()
        and not any(part == "__pycache__" or part.startswith(".") for part in p.relative_to(tests_dir).parts)
    )


def unmirrored_folders(tests_dir: Path, package_dir: Path) -> list[str]:
    """Folders right under ``tests_dir`` that name no package (a folder with an ``__init__.py``) of ``package_dir``,
    helpers/ and faults/ left out."""
    packages = {p.name for p in package_dir.iterdir() if (p / "__init__.py").is_file()}
    return [
        p.name
        for p in folders(tests_dir)
        if p.parent == tests_dir and p.name not in UNMIRRORED and p.name not in packages
    ]


def folders_without_init(tests_dir: Path) -> list[str]:
    return [p.relative_to(tests_dir).as_posix() for p in folders(tests_dir) if not (p / "__init__.py").is_file()]


def test_test_modules_and_conftests_import_only_the_helpers_of_the_suite():
    wrong = [
        f"{path.relative_to(TESTS_DIR.parent)} imports {name}"
        for path in python_files(TESTS_DIR)
        for name in foreign_imports(path.read_text(encoding="utf-8"), module_name(path), path.name == "__init__.py")
    ]
    assert not wrong, "move what they share into tests/helpers:\n" + "\n".join(wrong)


def test_the_import_check_finds_test_modules_conftests_and_relative_imports():
    source = textwrap.dedent(
        """
        import os
        import tests.sim.conftest
        import tests.helpers_old
        from tests.helpers.tracks import STADIUM
        from tests.helpers import tracks
        from tests import conftest, helpers
        from tests.phase2_rl.test_train import tiny_config
        from .test_protocol import CentreLineFollower
        from . import test_sections
        from .. import test_layering
        from vision_rl.sim import track

        def late():
            from tests.overtaking import test_baselines
        """
    )
    assert foreign_imports(source, "tests.evaluation.test_encoder_error") == [
        "tests.conftest",
        "tests.evaluation",
        "tests.evaluation.test_protocol",
        "tests.helpers_old",
        "tests.overtaking",
        "tests.phase2_rl.test_train",
        "tests.sim.conftest",
        "tests.test_layering",
    ]
    assert foreign_imports("from . import tracks\nfrom .tracks import STADIUM\n", "tests.helpers", True) == []
    assert foreign_imports("from .tracks import STADIUM\n", "tests.helpers.policies") == []


def test_every_test_folder_tests_a_package_and_is_a_package():
    assert unmirrored_folders(TESTS_DIR, PACKAGE_DIR) == []
    assert folders_without_init(TESTS_DIR) == []


def test_the_folder_checks_find_a_folder_of_no_package_and_a_folder_without_init(tmp_path):
    package, tests = tmp_path / "vision_rl", tmp_path / "tests"
    for folder in ("vision_rl/sim", "vision_rl/training", "tests/sim", "tests/helpers", "tests/faults", "tests/data"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "__init__.py").touch()
    (package / "data").mkdir()  # a folder of data files, not a package
    (tests / "phase2").mkdir()  # no such package, and no __init__.py
    (tests / "training").mkdir()  # a package's tests without an __init__.py
    (tests / "__pycache__").mkdir()
    (tests / "sim" / "__pycache__").mkdir()
    assert unmirrored_folders(tests, package) == ["data", "phase2"]
    assert folders_without_init(tests) == ["phase2", "training"]
