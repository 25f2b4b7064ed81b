"""The capture HDF5 file: round trip, refusal to overwrite, crash safety, resume, validation, full disk."""

from __future__ import annotations

import errno
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from vision_rl.capture import h5format
from vision_rl.capture.h5format import CaptureDiskFullError, CaptureFormatError, CaptureWriter, open_capture

HW_PX = (12, 20)
NAMES = tuple(f"t{i}" for i in range(27))
UNITS = ("m",) * 13 + ("m", "m", "m", "rad") + ("1/m",) * 10
DED = tuple(f"d{i}" for i in range(11))
DED_UNITS = ("m/s",) * 3 + ("m/s^2",) * 3 + ("rad/s",) * 3 + ("1", "rad")
ATTRS = {
    "track_name": "stadium",
    "track_geometry_hash": "abc123",
    "car_preset": "hatchback",
    "renderer_settings": {"camera": "hood", "fov_deg": 70.0, "msaa": 0},
    "seed": 42,
}


def batch(k: int, start: int = 0) -> dict[str, np.ndarray]:
    """k frames whose every value encodes its frame number, so a misplaced frame is caught."""
    i = np.arange(start, start + k)
    images = np.broadcast_to((i % 251).astype(np.uint8)[:, None, None, None], (k, *HW_PX, 3)).copy()
    images[:, 0, 0, 0] = (i // 251).astype(np.uint8)
    return {
        "images": images,
        "targets": (i[:, None] + np.arange(27) / 100).astype(np.float32),
        "dedicated": (-i[:, None] + np.arange(11) / 100).astype(np.float32),
        "pose": np.stack([i * 1.5, i * -2.0, i * 0.01], axis=1),
        "time_s": i / 60.0,
        "lap": (i // 10).astype(np.int32),
        "car_id": (i % 3).astype(np.int32),
    }


def writer(path: Path, **kw) -> CaptureWriter:
    return CaptureWriter(
        path,
        image_hw_px=HW_PX,
        target_names=NAMES,
        target_units=UNITS,
        dedicated_names=DED,
        dedicated_units=DED_UNITS,
        attrs=ATTRS,
        **kw,
    )


def assert_frames(cap, start: int, stop: int) -> None:
    expected = batch(stop - start, start)
    np.testing.assert_array_equal(cap.read_images(np.arange(start, stop)), expected["images"])
    np.testing.assert_array_equal(cap.targets[start:stop], expected["targets"])
    np.testing.assert_array_equal(cap.dedicated[start:stop], expected["dedicated"])
    np.testing.assert_array_equal(cap.pose[start:stop], expected["pose"])
    np.testing.assert_array_equal(cap.time_s[start:stop], expected["time_s"])
    np.testing.assert_array_equal(cap.lap[start:stop], expected["lap"])
    np.testing.assert_array_equal(cap.car_id[start:stop], expected["car_id"])


@pytest.mark.parametrize("compression", ["zstd", "lzf", "gzip", "none"])
def test_round_trip_shapes_dtypes_attributes(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path, compression=compression)
    w.append(**batch(5))
    w.append(**batch(7, 5))
    assert w.n_frames == 12
    w.close(complete=True)
    with open_capture(path) as cap:
        assert cap.n_frames == 12 and cap.complete
        assert cap.image_hw_px == HW_PX
        assert cap.images.dtype == np.uint8 and cap.images.shape == (12, *HW_PX, 3)
        assert cap.images.chunks == (1, *HW_PX, 3)  # one frame per chunk: a random read decodes one frame
        assert cap.targets.dtype == np.float32 and cap.targets.shape == (12, 27)
        assert cap.dedicated.dtype == np.float32 and cap.pose.dtype == np.float64
        assert cap.lap.dtype == np.int32 and cap.car_id.dtype == np.int32
        assert cap.target_names == list(NAMES) and cap.target_units == list(UNITS)
        assert cap.dedicated_names == list(DED) and cap.dedicated_units == list(DED_UNITS)
        assert cap.attrs["track_geometry_hash"] == "abc123" and cap.attrs["seed"] == 42
        assert cap.attrs["renderer_settings"] == ATTRS["renderer_settings"]  # dict back from JSON
        assert cap.attrs["package_version"] and cap.attrs["compression"] == compression
        assert_frames(cap, 0, 12)
        np.testing.assert_array_equal(cap.read_images([11, 0, 11]), batch(12)["images"][[11, 0, 11]])
        with pytest.raises(IndexError):
            cap.read_image(12)
    with h5py.File(path) as f:  # plain h5py readers see the per-dataset names and units too
        assert list(f["targets"].attrs["names"]) == list(NAMES)
        assert f["time"].attrs["units"] == "s"


def noisy_batch(k: int, seed: int) -> dict[str, np.ndarray]:
    """A batch whose images are half random noise (incompressible) and half flat: every byte must survive."""
    out = batch(k)
    rng = np.random.default_rng(seed)
    out["images"][:, : HW_PX[0] // 2] = rng.integers(0, 256, (k, HW_PX[0] // 2, HW_PX[1], 3), dtype=np.uint8)
    return out


@pytest.mark.parametrize("compression", ["zstd", "gzip"])
def test_codec_round_trips_bit_exactly_here_and_in_plain_h5py(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "cap.h5"
    frames = noisy_batch(9, seed=3)
    with writer(path, compression=compression) as w:
        w.append(**frames)
    with open_capture(path) as cap:
        np.testing.assert_array_equal(cap.read_images(np.arange(9), threads=2), frames["images"])
        np.testing.assert_array_equal(cap.read_images([4, 4, 0], threads=1), frames["images"][[4, 4, 0]])
        np.testing.assert_array_equal(cap.read_image(8), frames["images"][8])
    # The chunks are what HDF5's own deflate / Zstandard filter makes of them (hdf5plugin registers the latter).
    with h5py.File(path) as f:
        np.testing.assert_array_equal(f["images"][:9], frames["images"])
        filter_id = f["images"].id.get_create_plist().get_filter(0)[0]
        assert filter_id == (h5py.h5z.FILTER_DEFLATE if compression == "gzip" else 32015)


def test_caller_may_reuse_its_buffers_while_frames_are_compressed(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    frames = noisy_batch(12, seed=5)
    buf = {k: np.empty_like(v[:3]) for k, v in frames.items()}
    with writer(path, flush_interval_s=3600.0) as w:
        for start in range(0, 12, 3):
            for k, v in frames.items():
                buf[k][...] = v[start : start + 3]  # one buffer refilled for every batch, as a grabber does
            w.append(**buf)
        w.close(complete=True)
    with open_capture(path) as cap:
        assert cap.n_frames == 12
        np.testing.assert_array_equal(cap.read_images(np.arange(12)), frames["images"])
        np.testing.assert_array_equal(cap.targets, frames["targets"])
        np.testing.assert_array_equal(cap.lap, frames["lap"])


def test_gzip_file_resumes_with_its_own_codec(tmp_path: Path) -> None:
    path = tmp_path / "old.h5"
    frames = noisy_batch(6, seed=4)
    with writer(path, compression="gzip") as w:
        w.append(**{k: v[:4] for k, v in frames.items()})
    w = writer(path, resume=True)  # the default codec is zstd: a resumed file keeps its own
    assert w.compression == "gzip" and w.n_frames == 4
    w.append(**{k: v[4:] for k, v in frames.items()})
    w.close(complete=True)
    with open_capture(path) as cap:
        assert cap.attrs["compression"] == "gzip"
        np.testing.assert_array_equal(cap.read_images(np.arange(6), threads=2), frames["images"])
        np.testing.assert_array_equal(cap.read_image(5), frames["images"][5])


def test_files_of_format_1_without_checksums_are_refused(tmp_path: Path) -> None:
    path = _complete_file(tmp_path / "v1.h5")
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = 1
    with pytest.raises(CaptureFormatError, match=r"no checksums.*capture it again"):
        open_capture(path)


@pytest.mark.parametrize("compression", ["zstd", "lzf"])
def test_fingerprint_and_content_digest(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path, compression=compression)
    w.append(**noisy_batch(5, seed=1))
    w.close(complete=True)
    with open_capture(path) as cap:
        fp = cap.fingerprint
        assert fp["track_geometry_hash"] == "abc123" and fp["seed"] == 42 and fp["image_width"] == HW_PX[1]
        assert fp["renderer_settings"] == ATTRS["renderer_settings"]
        assert h5format.fingerprint_sha256(fp) == cap.attrs["fingerprint_sha256"]
        digest = cap.content_sha256()
        assert digest == cap.attrs["content_sha256"]
        np.testing.assert_array_equal(cap.read_images(np.arange(5)), noisy_batch(5, seed=1)["images"])
    with h5py.File(path, "r+") as f:  # an edit that keeps every checksum valid still changes the digest
        f["lap"][0] = 99
    with open_capture(path) as cap, pytest.raises(CaptureFormatError, match="content_sha256"):
        cap.content_sha256()


def test_corrupt_zstd_frame_is_named(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    with writer(path) as w:
        w.append(**batch(3))
    with h5py.File(path, "r+") as f:
        f["images"].id.write_direct_chunk((1, 0, 0, 0), b"not a zstd frame")
    with open_capture(path) as cap:
        np.testing.assert_array_equal(cap.read_image(0), batch(3)["images"][0])
        with pytest.raises(CaptureFormatError, match="frame 1"):
            cap.read_image(1)
        with pytest.raises(CaptureFormatError, match="frame 1"):
            cap.read_images([0, 1, 2], threads=2)


def test_existing_file_needs_force_and_complete_file_cannot_resume(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path)
    w.append(**batch(3))
    w.close(complete=True)
    with pytest.raises(FileExistsError, match="--force"):
        writer(path)
    with pytest.raises(CaptureFormatError, match="complete"):
        writer(path, resume=True)
    with pytest.raises(ValueError):
        writer(path, resume=True, force=True)
    writer(path, force=True).close()
    with open_capture(path) as cap:
        assert cap.n_frames == 0 and not cap.complete


def test_context_manager_leaves_file_incomplete(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    with writer(path) as w:
        w.append(**batch(4))
    with open_capture(path) as cap:
        assert cap.n_frames == 4 and not cap.complete


def test_bad_input_is_refused(tmp_path: Path) -> None:
    w = writer(tmp_path / "cap.h5")
    b = batch(2)
    with pytest.raises(ValueError, match="uint8"):
        w.append(**{**b, "images": b["images"].astype(np.float32)})
    with pytest.raises(ValueError, match="targets"):
        w.append(**{**b, "targets": b["targets"][:, :26]})
    with pytest.raises(ValueError, match="integers"):
        w.append(**{**b, "lap": np.array([0.5, 1.0])})
    w.append(**{**b, "lap": np.array([0.0, 1.0])})  # whole floats are fine
    assert w.n_frames == 2
    w.close()
    with pytest.raises(ValueError, match="attrs lack"):
        CaptureWriter(
            tmp_path / "x.h5",
            image_hw_px=HW_PX,
            target_names=NAMES,
            target_units=UNITS,
            dedicated_names=DED,
            dedicated_units=DED_UNITS,
            attrs={"seed": 1},
        )


_KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    from test_h5format import batch, writer
    w = writer({path!r}, flush_interval_s={interval})
    w.append(**batch(4))
    w.append(**batch(4, 4))
    w.flush()
    w.append(**batch(4, 8))  # after the last flush: may be lost, must not corrupt the file
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


@pytest.mark.parametrize("interval", [0.0, 3600.0])
def test_killed_writer_leaves_readable_incomplete_file_that_resumes(tmp_path: Path, interval: float) -> None:
    path = tmp_path / "cap.h5"
    code = _KILLED_WRITER.format(tests=str(Path(__file__).parent), path=str(path), interval=interval)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == -9, proc.stderr
    with open_capture(path) as cap:
        assert not cap.complete
        # Flushing after every append (interval 0) keeps all 12 frames; otherwise the explicit flush's 8 survive.
        assert cap.n_frames == (12 if interval == 0.0 else 8)
        n = cap.n_frames
        assert_frames(cap, 0, n)
    w = writer(path, resume=True)
    assert w.n_frames == n
    w.append(**batch(5, n))
    w.close(complete=True)
    with open_capture(path) as cap:
        assert cap.complete and cap.n_frames == n + 5
        assert_frames(cap, 0, n + 5)


def _damage_first_chunk(path: Path, name: str) -> None:
    """Overwrite the start of ``name``'s first chunk on disk, as a kill inside HDF5's rewrite of it would."""
    with h5py.File(path, "r") as f:
        offset = f[name].id.get_chunk_info_by_coord((0,) * f[name].ndim).byte_offset
    with open(path, "r+b") as fh:
        fh.seek(offset)
        fh.write(b"\xff" * 64)


def test_committed_rows_of_a_chunk_damaged_in_its_rewrite_are_restored_from_the_journal(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path, flush_interval_s=0.0)
    w.append(**batch(10))
    w.append(**batch(8, 10))  # rewrites the chunk holding the 10 committed rows
    w.close()
    journal = h5format.journal_path(path)
    assert journal.exists()
    _damage_first_chunk(path, "targets")
    with open_capture(path) as cap, pytest.raises(CaptureFormatError, match=r"frames 0\.\.17.*--resume"):
        _ = cap.targets
    w = writer(path, resume=True)
    assert w.n_frames == 18
    w.append(**batch(3, 18))
    w.close(complete=True)
    assert not journal.exists()  # a complete file needs none
    with open_capture(path) as cap:
        assert cap.complete and cap.n_frames == 21
        assert_frames(cap, 0, 21)


def test_a_bad_or_foreign_journal_is_named_when_needed_and_ignored_otherwise(tmp_path: Path) -> None:
    path, other = tmp_path / "cap.h5", tmp_path / "other.h5"
    for p in (path, other):
        w = (
            writer(p)
            if p == path
            else CaptureWriter(
                p,
                image_hw_px=HW_PX,
                target_names=NAMES,
                target_units=UNITS,
                dedicated_names=DED,
                dedicated_units=DED_UNITS,
                attrs={**ATTRS, "seed": 7},
            )
        )
        w.append(**batch(5))
        w.close()
    journal = h5format.journal_path(path)
    before = path.read_bytes()
    _damage_first_chunk(path, "targets")  # now the resume needs the journal
    damaged = path.read_bytes()
    shutil.copy(h5format.journal_path(other), journal)
    with pytest.raises(CaptureFormatError, match="belongs to another capture"):
        writer(path, resume=True)
    journal.write_bytes(b"PK\x03\x04 half a zip")
    with pytest.raises(CaptureFormatError, match=r"journal of cap\.h5 is damaged"):
        writer(path, resume=True)
    assert path.read_bytes() == damaged  # refused before anything was changed
    # The file's own committed rows match their hash: a foreign journal is not needed, and is replaced.
    path.write_bytes(before)
    shutil.copy(h5format.journal_path(other), journal)
    w = writer(path, resume=True)
    w.append(**batch(3, 5))
    w.close(complete=True)
    with open_capture(path) as cap:
        assert cap.n_frames == 8
        assert_frames(cap, 0, 8)
    writer(path, force=True).close()  # starting over drops the old file's journal
    assert not journal.exists()


def test_resume_refuses_other_settings_and_creates_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path)
    w.append(**batch(2))
    w.close()
    with pytest.raises(CaptureFormatError, match="track_geometry_hash"):
        CaptureWriter(
            path,
            image_hw_px=HW_PX,
            target_names=NAMES,
            target_units=UNITS,
            dedicated_names=DED,
            dedicated_units=DED_UNITS,
            attrs={**ATTRS, "track_geometry_hash": "other"},
            resume=True,
        )
    with pytest.raises(CaptureFormatError, match="image_width"):
        CaptureWriter(
            path,
            image_hw_px=(HW_PX[0], HW_PX[1] + 4),
            target_names=NAMES,
            target_units=UNITS,
            dedicated_names=DED,
            dedicated_units=DED_UNITS,
            attrs=ATTRS,
            resume=True,
        )
    fresh = writer(tmp_path / "new.h5", resume=True)
    assert fresh.n_frames == 0
    fresh.close()


def test_disk_full_raises_clear_error_and_keeps_flushed_frames(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "cap.h5"
    w = writer(path, flush_interval_s=0.0)
    w.append(**batch(3))
    real_flush = h5py.File.flush

    def full_disk(self):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(h5py.File, "flush", full_disk)
    with pytest.raises(CaptureDiskFullError, match=r"disk full after 3 frames") as info:
        w.append(**batch(2, 3))
    assert info.value.errno == errno.ENOSPC and str(path) in str(info.value)
    monkeypatch.setattr(h5py.File, "flush", real_flush)
    with pytest.raises(RuntimeError):
        w.append(**batch(1, 5))
    with open_capture(path) as cap:
        assert not cap.complete and cap.n_frames >= 3
        assert_frames(cap, 0, 3)


def _complete_file(path: Path, k: int = 6) -> Path:
    w = writer(path)
    w.append(**batch(k))
    w.close(complete=True)
    return path


def test_missing_or_wrong_datasets_and_lengths_are_named(tmp_path: Path) -> None:
    cases = {
        "missing dataset 'lap'": lambda f: f.__delitem__("lap"),
        "dtype": lambda f: (f.__delitem__("car_id"), f.create_dataset("car_id", data=np.zeros(6, np.float32))),
        "shape": lambda f: (f.__delitem__("pose"), f.create_dataset("pose", data=np.zeros((6, 2)))),
        "different lengths": lambda f: f["time"].resize(5, axis=0),
        "missing attributes": lambda f: f.attrs.__delitem__("track_geometry_hash"),
    }
    for i, (message, damage) in enumerate(cases.items()):
        path = _complete_file(tmp_path / f"c{i}.h5")
        with h5py.File(path, "r+") as f:
            damage(f)
        with pytest.raises(CaptureFormatError, match=message) as info:
            open_capture(path)
        assert str(path) in str(info.value)


def test_truncated_corrupt_and_absent_files_are_named(tmp_path: Path) -> None:
    good = _complete_file(tmp_path / "good.h5", k=20)
    truncated = tmp_path / "truncated.h5"
    data = good.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    for path in (truncated, garbage, tmp_path / "absent.h5"):
        with pytest.raises(CaptureFormatError) as info:
            with open_capture(path) as cap:  # a file that opens must fail on reading its frames
                cap.read_images(range(cap.n_frames))
        assert str(path) in str(info.value)


def test_incomplete_file_trusts_committed_count(tmp_path: Path) -> None:
    # A kill between a dataset resize and the flush leaves datasets longer than n_frames: frames beyond are ignored.
    path = tmp_path / "cap.h5"
    w = writer(path)
    w.append(**batch(4))
    w.close()
    with h5py.File(path, "r+") as f:
        f["images"].resize(6, axis=0)
        f["targets"].resize(5, axis=0)
    with open_capture(path) as cap:
        assert cap.n_frames == 4 and cap.targets.shape == (4, 27)
    shutil.copy(path, tmp_path / "copy.h5")
    with h5py.File(tmp_path / "copy.h5", "r+") as f:
        f.attrs["n_frames"] = 7
    with pytest.raises(CaptureFormatError, match="shorter than the 7 committed"):
        open_capture(tmp_path / "copy.h5")


def test_package_version_is_recorded() -> None:
    assert isinstance(h5format.package_version(), str) and h5format.package_version()
