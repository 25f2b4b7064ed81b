"""The records a table reads: each read once through :class:`Records`, refused unless sealed (:func:`record_damage`),
and sealed in place by :func:`seal_record_file` (what ``scripts/seal_records.py`` runs)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from vision_rl.evaluation.leaderboard import EVALUATION_FORMAT, OUTPUT_PATH_KEYS, seal_evaluation
from vision_rl.files import CONTENT_KEY, atomic_write, content_damage, json_text, parse_json, sealed_record

#: How a table names the results folder in its links; :func:`fill_page` puts the page's path to it there.
RESULTS = "RESULTS/"

#: The command that seals a record written before records were sealed (or transcribed by hand) once it is checked.
SEAL_COMMAND = ".venv/bin/python scripts/seal_records.py"


class ReportError(ValueError):
    """A record is missing or lacks a figure a table states, or a page's markers do not pair."""


class Records:
    """The JSON records under ``results_dir``, each read once, by their path relative to it."""

    def __init__(self, results_dir: str | os.PathLike[str], check: bool = True) -> None:
        self.results_dir = Path(results_dir)
        self.check = check
        """Refuse a record without its seal (:func:`record_damage`); off only to list the records a table reads."""
        self._read: dict[str, Any] = {}
        self.last: Path | None = None
        """The record read last: where a table that fails on a record's content was reading."""

    def __call__(self, relative_path: str) -> Any:
        if relative_path not in self._read:
            path = self.results_dir / relative_path
            if not path.is_file():
                raise ReportError(f"the record {path} is missing")
            try:
                record = parse_json(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise ReportError(f"the record {path} is not readable JSON: {exc}") from None
            damage = record_damage(record) if self.check else None
            if damage is not None:
                raise ReportError(f"the record {path} {damage}")
            self._read[relative_path] = record
        self.last = self.results_dir / relative_path
        return self._read[relative_path]


def record_damage(record: Any) -> str | None:
    """None when ``record`` is a JSON object carrying the SHA-256 of its content, else what is wrong and what to do,
    as the end of a sentence naming the file. Records of format 1 (before seals, and every transcribed record until
    sealed) have no hash: a table states nothing an edit or a flipped bit could have changed unseen."""
    if not isinstance(record, dict):
        return f"is {type(record).__name__}, not a JSON object"
    if CONTENT_KEY not in record:
        return f"has no {CONTENT_KEY} (format 1, before records were sealed): check it, then `{SEAL_COMMAND} PATH`"
    damage = content_damage(record, OUTPUT_PATH_KEYS if record.get("format") == EVALUATION_FORMAT else ())
    return (
        None
        if damage is None
        else f"{damage}; measure it again, or if the edit was meant, seal it with `{SEAL_COMMAND} PATH`"
    )


def sealed(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` sealed the way its kind is read back: an evaluation without its output paths
    (:func:`~vision_rl.evaluation.leaderboard.seal_evaluation`), any other over all of it."""
    if record.get("format") == EVALUATION_FORMAT:
        return seal_evaluation(dict(record))
    return sealed_record(record)


def seal_record_file(path: str | os.PathLike[str]) -> bool:
    """Seal the record at ``path`` in place (:func:`sealed`), keeping its layout (indented or one line); False when it
    was sealed and whole already. A sealed record whose content changed is refused: a hand edit is sealed on
    purpose, after removing its old ``content_sha256``."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    try:
        record = parse_json(text)
    except ValueError as exc:
        raise ReportError(f"{path}: not readable JSON: {exc}") from None
    if not isinstance(record, dict):
        raise ReportError(f"{path}: not a JSON object, not a record")
    if CONTENT_KEY in record:
        damage = record_damage(record)
        if damage is not None:
            raise ReportError(f"{path}: {damage.split(';')[0]}; remove its {CONTENT_KEY} to seal it as it is now")
        return False
    lines = text.lstrip().splitlines()
    indent = len(lines[1]) - len(lines[1].lstrip(" ")) if len(lines) > 1 else None
    sealed_text = json_text(sealed(record), indent=indent) + ("\n" if text.endswith("\n") else "")
    atomic_write(path, lambda tmp: tmp.write_text(sealed_text, encoding="utf-8"))
    return True
