"""Seeded single-bit flips of a file, and the rule every flip must meet: the loader gives the original content back,
or refuses in one line that names the file; never a traceback, never other content."""

from __future__ import annotations

import dataclasses
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np


def same_arrays(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """The same names holding equal arrays: a flipped file that loads is harmless only so."""
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def zip_regions(
    path: Path, is_data: Callable[[str], bool], header: Callable[[bytes], int]
) -> tuple[list[range], list[range]]:
    """(metadata, data) byte ranges of an uncompressed zip: the members ``is_data`` names hold data after their own
    ``header(bytes)`` bytes; the zip's headers and directory and every other member are metadata."""
    raw = path.read_bytes()
    data = []
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            local = info.header_offset
            start = local + 30 + int.from_bytes(raw[local + 26 : local + 28], "little")
            start += int.from_bytes(raw[local + 28 : local + 30], "little")
            if is_data(info.filename):
                data.append(range(start + header(raw[start : start + info.file_size]), start + info.file_size))
    return uncovered(data, len(raw)), [r for r in data if len(r)]


def uncovered(ranges: list[range], size: int) -> list[range]:
    """The byte ranges of ``[0, size)`` that none of ``ranges`` covers (a file's metadata around its data)."""
    covered = np.zeros(size, bool)
    for r in ranges:
        covered[r.start : r.stop] = True
    edges = np.flatnonzero(np.diff(np.concatenate([[1], covered.view(np.int8), [1]])))
    return [range(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True) if b > a]


def npz_regions(path: Path) -> tuple[list[range], list[range]]:
    """(metadata, data) of an uncompressed ``.npz``: each member's ``.npy`` header and the ``meta`` member are
    metadata, the other members' array bytes data."""
    return zip_regions(
        path, lambda name: name != "meta.npy", lambda member: 10 + int.from_bytes(member[8:10], "little")
    )


def torch_regions(path: Path) -> tuple[list[range], list[range]]:
    """(metadata, data) of a ``torch.save`` file: its tensors' storages are data, the pickled index, its version
    records and the zip's headers metadata."""
    return zip_regions(path, lambda name: "/data/" in name and name.rsplit("/", 1)[-1].isdigit(), lambda _: 0)


def sample_flips(regions: list[range], n: int, seed: int) -> list[tuple[int, int]]:
    """``n`` (byte offset, bit) pairs drawn uniformly over the bytes of ``regions``."""
    offsets = np.concatenate([np.arange(r.start, r.stop) for r in regions])
    rng = np.random.default_rng(seed)
    return [(int(offsets[i]), int(rng.integers(8))) for i in rng.choice(len(offsets), n, replace=False)]


def flipped_copies(original: Path, flips: list[tuple[int, int]], target: Path) -> Iterator[tuple[int, int]]:
    """Write ``original`` with each flip in turn to ``target``, yielding the flip; the original stays whole."""
    data = original.read_bytes()
    for offset, bit in flips:
        changed = bytearray(data)
        changed[offset] ^= 1 << bit
        target.write_bytes(bytes(changed))
        yield offset, bit


@dataclasses.dataclass
class FlipOutcomes:
    """How the flips of one file ended: read back unchanged, or refused (with the first refusal's message)."""

    unchanged: int = 0
    refused: int = 0
    example: str = ""


def check_flips(
    original: Path,
    flips: list[tuple[int, int]],
    target: Path,
    load: Callable[[Path], Any],
    expected: Any,
    refusal: type[BaseException],
    same: Callable[[Any, Any], bool] = lambda a, b: a == b,
) -> FlipOutcomes:
    """Every flip of ``original`` (written to ``target``) loads as ``expected`` or raises ``refusal`` with one
    line naming ``target``; any other outcome fails with the flip named."""
    outcomes = FlipOutcomes()
    for offset, bit in flipped_copies(original, flips, target):
        judge_flip(outcomes, f"bit {bit} of byte {offset} of {original.name}", target, load, expected, refusal, same)
    return outcomes


def judge_flip(
    outcomes: FlipOutcomes,
    where: str,
    path: Path,
    load: Callable[[Path], Any],
    expected: Any,
    refusal: type[BaseException],
    same: Callable[[Any, Any], bool],
) -> None:
    """Count ``load(path)`` of a flipped file in ``outcomes``: ``expected`` back, or ``refusal`` in one line naming
    the file; anything else fails with the flip (``where``) named."""
    try:
        loaded = load(path)
    except refusal as exc:
        message = str(exc)
        assert "\n" not in message.strip() and "Traceback" not in message, f"{where}: {message}"
        assert path.name in message, f"{where}: the refusal does not name the file: {message}"
        outcomes.refused += 1
        outcomes.example = outcomes.example or message
        return
    assert same(loaded, expected), f"{where}: loaded content that differs from what was written"
    outcomes.unchanged += 1
