"""The package's one atomic write: what it guarantees, and that nothing else writes a file by renaming it."""

from __future__ import annotations

import ast
import errno
import hashlib
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from vision_rl.files import (
    CONTENT_KEY,
    ArtifactWriteError,
    atomic_write,
    content_damage,
    content_sha256,
    file_sha256,
    first_line,
    json_text,
    parse_json,
    sealed_record,
    temporary_path,
    write_json,
)

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "vision_rl"


def test_a_write_returns_the_sha256_of_what_it_wrote_and_leaves_no_staging_file(tmp_path):
    path = tmp_path / "a.bin"
    sha = atomic_write(path, lambda tmp: tmp.write_bytes(b"abc"))
    assert sha == hashlib.sha256(b"abc").hexdigest() == file_sha256(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]
    assert temporary_path(path).parent == tmp_path and temporary_path(path).name.startswith(".a.bin.")


def test_a_failed_write_keeps_the_previous_file_and_names_it(tmp_path):
    path = tmp_path / "a.json"
    write_json(path, {"x": 1})

    def full_disk(tmp: Path) -> None:
        tmp.write_bytes(b"{partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(ArtifactWriteError, match=r"cannot write .*a\.json: No space left on device") as info:
        atomic_write(path, full_disk)
    assert info.value.errno == errno.ENOSPC
    assert json.loads(path.read_text()) == {"x": 1} and sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]


def strict_loads(text: str):
    """``json.loads`` that refuses the bare NaN, Infinity and -Infinity of Python's default JSON."""

    def refuse(constant: str):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_a_missing_or_non_finite_number_is_written_as_null(tmp_path):
    record = {"lap": float("nan"), "laps": [1.5, float("inf"), (float("-inf"), 2)], "deep": {"x": [{"y": math.nan}]}}
    expected = {"lap": None, "laps": [1.5, None, [None, 2]], "deep": {"x": [{"y": None}]}}
    assert strict_loads(json_text(record)) == expected
    write_json(tmp_path / "r.json", record)
    assert strict_loads((tmp_path / "r.json").read_text()) == expected
    assert json_text({"b": 1, "a": np.float64("nan")}, sort_keys=True) == '{"a": null, "b": 1}'
    with pytest.raises(ValueError, match="not JSON: NaN"):
        strict_loads(json.dumps({"lap": float("nan")}))  # what the writers wrote before


def test_an_interrupted_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "a.txt"
    path.write_text("old")

    def interrupted(tmp: Path) -> None:
        tmp.write_text("new, half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, interrupted)
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def renames_outside_files(source: str) -> list[int]:
    """Lines that rename or replace a file (``os.replace``, ``os.rename``, ``Path.rename``/``replace``,
    ``shutil.move``): only vision_rl/files.py may."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            owner = node.func.value
            name = node.func.attr
            if name in ("replace", "rename") and isinstance(owner, ast.Name) and owner.id == "os":
                lines.append(node.lineno)
            elif name == "move" and isinstance(owner, ast.Name) and owner.id == "shutil":
                lines.append(node.lineno)
            elif name == "rename" and node.args:
                lines.append(node.lineno)
    return lines


def test_the_checker_finds_a_hand_written_rename():
    assert renames_outside_files("import os\nos.replace(a, b)\nx.rename(y)\nshutil.move(a, b)\n") == [2, 3, 4]
    assert renames_outside_files("s = 'a'.replace('a', 'b')\n") == []


def test_only_files_py_renames_files():
    found = {
        str(path.relative_to(PACKAGE_DIR)): lines
        for path in sorted(PACKAGE_DIR.rglob("*.py"))
        if path.name != "files.py" or path.parent != PACKAGE_DIR
        for lines in [renames_outside_files(path.read_text(encoding="utf-8"))]
        if lines
    }
    assert not found, f"write through vision_rl.files.atomic_write instead: {found}"


def json_written_unchecked(source: str) -> list[int]:
    """Lines where ``json.dumps(...)`` or ``json.dump(...)`` is written (an argument of a ``write``, ``write_text``
    or ``np.array`` call, or ``json.dump`` itself): every writer goes through vision_rl.files.json_text."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
            continue
        if node.func.attr == "dump" and isinstance(node.func.value, ast.Name) and node.func.value.id == "json":
            lines.append(node.lineno)
        elif node.func.attr in ("write", "write_text", "array") or getattr(node.func, "id", "") == "print":
            for arg in ast.walk(ast.Module(body=[ast.Expr(a) for a in node.args], type_ignores=[])):
                if isinstance(arg, ast.Call) and isinstance(arg.func, ast.Attribute) and arg.func.attr == "dumps":
                    lines.append(node.lineno)
    return sorted(set(lines))


def test_the_checker_finds_a_json_line_written_without_json_text():
    source = "f.write(json.dumps(r) + '\\n')\np.write_text(json.dumps(r))\njson.dump(r, f)\nf.write(json_text(r))\n"
    assert json_written_unchecked(source) == [1, 2, 3]


def test_every_json_writer_goes_through_json_text():
    found = {
        str(path.relative_to(PACKAGE_DIR)): lines
        for path in sorted(PACKAGE_DIR.rglob("*.py"))
        for lines in [json_written_unchecked(path.read_text(encoding="utf-8"))]
        if lines
    }
    assert not found, f"write JSON through vision_rl.files.json_text (null for NaN) instead: {found}"


def test_a_sealed_record_keeps_its_hash_through_a_file_and_any_change_breaks_it(tmp_path):
    record = sealed_record({"lap_s": 91.4, "laps": (1, 2), "missing": float("nan"), "plot": "a.png"})
    path = tmp_path / "r.json"
    write_json(path, record)
    back = parse_json(path.read_text())
    assert content_damage(back) is None  # tuples as lists, NaN as null: the hash is of what a reader parses
    assert "the file changed" in content_damage({**back, "lap_s": 59.999})
    assert content_damage({k: v for k, v in back.items() if k != CONTENT_KEY}) == f"has no {CONTENT_KEY}"
    # A key left out (an output path added after sealing) changes nothing; one kept does.
    left_out = {**back, CONTENT_KEY: content_sha256(back, ("plot",))}
    assert content_damage({**left_out, "plot": "b.png"}, ("plot",)) is None
    assert content_damage({**left_out, "lap_s": 1.0}, ("plot",)) is not None


def test_json_nested_past_the_parsers_depth_is_a_value_error():
    with pytest.raises(ValueError, match="nested too deeply"):
        parse_json("[" * 100_000 + "]" * 100_000)
    assert parse_json('{"a": [1, {"b": null}]}') == {"a": [1, {"b": None}]}


def test_an_errors_first_line_is_its_message_first_line_or_its_type_name():
    assert first_line(ValueError("  bad value\n  at line 3\n")) == "bad value"
    assert first_line(KeyError()) == "KeyError"
    assert first_line(RuntimeError("   ")) == "RuntimeError"


def test_only_files_py_takes_an_errors_first_line():
    """One implementation: an inline ``str(exc).splitlines()[0]`` fails (IndexError) on an empty message."""
    idiom = re.compile(r"str\(\w+\)(\.strip\(\))?\.splitlines\(\)\[0\]")
    found = [
        f"{path.relative_to(PACKAGE_DIR)}:{n}"
        for path in sorted(PACKAGE_DIR.rglob("*.py"))
        if path.name != "files.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if idiom.search(line)
    ]
    assert not found, f"use vision_rl.files.first_line: {found}"


def test_a_json_record_under_a_file_is_refused_in_one_line_naming_it(tmp_path):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(ArtifactWriteError, match=r"cannot write .*a_file/record.json: File exists"):
        write_json(tmp_path / "a_file" / "record.json", {"a": 1})
