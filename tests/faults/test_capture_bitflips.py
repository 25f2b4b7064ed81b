"""Generated faults of capture files: single-bit flips at seeded positions over a small capture's HDF5 metadata and
over its data (the image chunks and the table chunks), fed to every path that reads a capture: open and read
everything, the dataset train-repr trains on, and a resume. Each flip must end in the original content or in one line
that names the file: never a traceback, never other content."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.helpers.bitflips import FlipOutcomes, judge_flip, same_arrays, sample_flips, uncovered
from tests.helpers.captures import write_synthetic_capture
from vision_rl.capture.h5format import (
    ALL_DATASETS,
    CaptureFormatError,
    CaptureWriter,
    crashing_captures,
    journal_path,
    open_capture,
    probe_captures,
)
from vision_rl.capture.sharded import ShardedCaptureConfig, open_manifest, plan_shards, write_manifest
from vision_rl.datasets import CaptureDataset

HW_PX = (16, 24)
N_FRAMES = 16
TABLES = ("targets", "dedicated", "pose", "time_s", "lap", "car_id")
#: Flips per region and path (each path reads every flip; a child process probes each set once).
FLIPS = 20
SEEDS = {"metadata": 11, "images": 22, "tables": 33}


def regions(path: Path) -> dict[str, list[range]]:
    """Byte ranges of a capture file: ``images`` (the stored image chunks), ``tables`` (the table chunks) and
    ``metadata`` (every other byte: superblock, object headers, attributes, chunk indexes, heaps)."""
    size = path.stat().st_size
    found: dict[str, list[range]] = {"images": [], "tables": []}
    with h5py.File(path, "r") as f:
        for name in ALL_DATASETS:
            kind = "images" if name == "images" else "tables"
            f[name].id.chunk_iter(
                lambda info, kind=kind: found[kind].append(range(info.byte_offset, info.byte_offset + info.size))
            )
    found["metadata"] = uncovered(found["images"] + found["tables"], size)
    return found


def everything(cap) -> dict[str, np.ndarray]:
    return {
        "images": cap.read_images(np.arange(cap.n_frames)),
        **{name: getattr(cap, name) for name in TABLES},
        "complete": np.asarray(cap.complete),
    }


def read_all(path: Path) -> dict[str, np.ndarray]:
    probe_captures([path])
    with open_capture(path) as cap:
        cap.content_sha256()
        return everything(cap)


def train_repr_reads(path: Path) -> dict[str, np.ndarray]:
    """What train-repr's data module reads: the catalogue (targets, laps, cars) and every frame in batches."""
    data = CaptureDataset.from_path(str(path))
    try:
        images, targets = data.__getitems__(list(range(len(data)))).images, data.targets
        return {"images": images.numpy(), "targets": targets, "lap": data.catalogue.lap}
    finally:
        data.close()


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> dict[str, Path]:
    """A complete capture and an incomplete one with its journal (16 frames of 16x24 px each)."""
    root = tmp_path_factory.mktemp("bitflips")
    complete, incomplete = root / "complete.h5", root / "incomplete.h5"
    write_synthetic_capture(complete, n_laps=4, frames_per_lap=4, image_hw_px=HW_PX)
    write_synthetic_capture(incomplete, n_laps=4, frames_per_lap=4, image_hw_px=HW_PX, complete=False)
    assert journal_path(incomplete).exists()
    return {"complete": complete, "incomplete": incomplete}


def flipped_copies(original: Path, flips: list[tuple[int, int]], folder: Path) -> list[tuple[Path, str]]:
    """A copy of ``original`` per flip in ``folder``, each (path, which bit)."""
    data = original.read_bytes()
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i, (offset, bit) in enumerate(flips):
        changed = bytearray(data)
        changed[offset] ^= 1 << bit
        path = folder / f"flip{i:03d}.h5"
        path.write_bytes(bytes(changed))
        out.append((path, f"bit {bit} of byte {offset} of {original.name}"))
    return out


@pytest.fixture(scope="module")
def flipped(captures, tmp_path_factory) -> dict[tuple[str, str], list[tuple[Path, str]]]:
    """The flipped copies of every test of this module, by (capture, region), all probed by one child process: the
    loaders' own probes then find them known, and only a file that crashed HDF5 is probed again (a child process
    per test cost more than the reads it guards)."""
    root = tmp_path_factory.mktemp("flipped")
    out = {}
    for name, seed_offset in (("complete", 0), ("incomplete", 1)):
        original = captures[name]
        for region, spans in regions(original).items():
            flips = sample_flips(spans, FLIPS, seed=seed_offset + SEEDS[region])
            out[name, region] = flipped_copies(original, flips, root / f"{name}-{region}")
    crashing_captures([path for files in out.values() for path, _ in files])
    return out


def outcomes(files: list[tuple[Path, str]], load, expected: dict[str, np.ndarray]) -> dict[str, int]:
    """Each file loads as ``expected`` or is refused in one line naming it; any other outcome fails the test."""
    counts = FlipOutcomes()
    for path, where in files:
        judge_flip(counts, where, path, load, expected, CaptureFormatError, same_arrays)
    return {"unchanged": counts.unchanged, "refused": counts.refused}


@pytest.mark.parametrize("region", ["metadata", "images", "tables"])
def test_bit_flips_in_a_capture_file_load_the_original_or_are_refused_naming_it(captures, flipped, region, fault):
    original = captures["complete"]
    files = flipped["complete", region]
    read = outcomes(files, read_all, read_all(original))
    dataset = outcomes(files, train_repr_reads, train_repr_reads(original))
    # Every flip is accounted for, and the sample reaches bytes the checks read (a region nobody reads would pass).
    assert sum(read.values()) == sum(dataset.values()) == len(files) == FLIPS
    assert read["refused"] > 0 and dataset["refused"] > 0, (read, dataset)
    fault.recovered(
        f"{FLIPS} single-bit flips over a capture file's {region}",
        f"open and read: {read['unchanged']} unchanged, {read['refused']} refused in one line; train-repr's "
        f"dataset: {dataset['unchanged']} unchanged, {dataset['refused']} refused; no traceback, no other content",
    )


def _resume_and_read(path: Path, source: Path) -> dict[str, np.ndarray]:
    """Resume ``path`` (a flipped copy of ``source``, beside a copy of its journal), append 4 frames and read the
    committed ones back."""
    shutil.copy(journal_path(source), journal_path(path))
    with open_capture(source) as cap:
        attrs = {k: cap.attrs[k] for k in ("track_name", "track_geometry_hash", "car_preset", "renderer_settings")}
        names = (cap.target_names, cap.target_units, cap.dedicated_names, cap.dedicated_units)
        attrs["seed"] = cap.attrs["seed"]
    writer = CaptureWriter(
        path,
        image_hw_px=HW_PX,
        target_names=names[0],
        target_units=names[1],
        dedicated_names=names[2],
        dedicated_units=names[3],
        attrs=attrs,
        resume=True,
    )
    n = writer.n_frames
    k = 4
    writer.append(
        np.zeros((k, *HW_PX, 3), np.uint8),
        np.zeros((k, 27), np.float32),
        np.zeros((k, 11), np.float32),
        np.zeros((k, 3)),
        np.arange(n, n + k) / 60.0,
        np.full(k, 99),
        np.zeros(k),
    )
    writer.close()
    with open_capture(path) as cap:
        got = everything(cap)
    return {name: value[:n] if value.ndim else value for name, value in got.items()} | {"n": np.asarray(n)}


@pytest.mark.parametrize("region", ["metadata", "images", "tables"])
def test_bit_flips_before_a_resume_resume_the_original_or_are_refused_naming_it(captures, flipped, region, fault):
    original = captures["incomplete"]
    files = flipped["incomplete", region]
    with open_capture(original) as cap:
        expected = everything(cap) | {"n": np.asarray(cap.n_frames)}
    counts = outcomes(files, lambda path: _resume_and_read(path, original), expected)
    assert sum(counts.values()) == len(files) == FLIPS, counts
    # A resume rewrites damaged table rows from the journal (it matches the last commit's hash); damaged images and
    # metadata have no second copy, so some of those flips are refused.
    assert counts["unchanged"] == FLIPS if region == "tables" else counts["refused"] > 0, counts
    fault.recovered(
        f"{FLIPS} single-bit flips over an incomplete capture's {region}, then capture --resume",
        f"{counts['unchanged']} resumed with every committed frame unchanged, {counts['refused']} refused in one line "
        "naming the file; no traceback, no other content",
    )


def test_bit_flips_in_a_shard_are_refused_through_its_manifest(tmp_path, fault):
    cfg = ShardedCaptureConfig(out=str(tmp_path / "cap.json"), laps=2, cars=1, image_hw_px=HW_PX, workers=2)
    shards = plan_shards(cfg)
    for i, shard in enumerate(shards):
        write_synthetic_capture(Path(shard.out), n_laps=2, frames_per_lap=4, image_hw_px=HW_PX, seed=i)
    write_manifest(cfg, shards, {"seed": cfg.seed})
    shard = Path(shards[1].out)
    pristine = tmp_path / "pristine.h5"
    shutil.copy(shard, pristine)
    expected = train_repr_reads(Path(cfg.out))
    flips = sample_flips(regions(pristine)["metadata"] + regions(pristine)["tables"], 6, seed=5)
    counts = {"unchanged": 0, "refused": 0}
    copies = flipped_copies(pristine, flips, tmp_path / "flipped")
    crashing_captures([path for path, _ in copies])  # one child process probes them all
    for (path, _), (offset, bit) in zip(copies, flips, strict=True):
        shard.unlink()
        shard.symlink_to(path)  # the manifest's shard, read through the link: the probe knows the file it resolves to
        try:
            open_manifest(cfg.out)
            got = train_repr_reads(Path(cfg.out))
        except CaptureFormatError as exc:
            message = str(exc)
            assert "\n" not in message and shard.name in message, message
            counts["refused"] += 1
            continue
        assert same_arrays(got, expected), f"bit {bit} of byte {offset}: other content loaded"
        counts["unchanged"] += 1
    fault.recovered(
        "6 single-bit flips over a shard of a sharded capture",
        f"{counts['unchanged']} unchanged, {counts['refused']} refused naming the shard",
    )


def test_an_attribute_that_crashes_hdf5_is_refused_naming_the_file(captures, tmp_path, fault):
    # The class bits of the vlen-string datatype of the attribute target_units: HDF5 segfaults reading the flipped
    # type, so without the probe in a child process this test's own process would die.
    data = bytearray(captures["incomplete"].read_bytes())
    at = data.find(b"target_units\x00") + 17
    assert data[at] == 0x01
    data[at] ^= 0b10
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(bytes(data))
    before = damaged.read_bytes()
    for read in (
        lambda: CaptureDataset.from_path(str(damaged)),
        lambda: _resume_and_read(damaged, captures["incomplete"]),
    ):
        with pytest.raises(CaptureFormatError) as info:
            read()
        message = str(info.value)
        assert len(message.splitlines()) == 1 and str(damaged) in message and "damaged file" in message, message
    assert damaged.read_bytes() == before
    fault.refused("an attribute's datatype damaged so that HDF5 crashes reading it", message)
