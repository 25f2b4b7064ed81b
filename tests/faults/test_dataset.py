"""Faults of capture files as datasets: flipped bytes in every array, files without checksums, edited attributes
and content, all refused with a message that names the file, the dataset and the frame."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from tests.helpers.captures import write_synthetic_capture
from vision_rl.capture.h5format import ALL_DATASETS, CaptureFormatError, open_capture
from vision_rl.datasets import FrameCatalogue

N_FRAMES = 16


@pytest.fixture
def capture_file(tmp_path: Path) -> Path:
    path = tmp_path / "cap.h5"
    write_synthetic_capture(path, n_laps=4, frames_per_lap=4, image_hw_px=(16, 24))  # 16 frames
    return path


def flip_byte(path: Path, dataset: str, frame: int) -> None:
    """Flip one bit of the stored chunk holding ``frame`` of ``dataset``, in the file's bytes (below HDF5)."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        chunk_rows = ds.chunks[0]
        coords = (frame // chunk_rows * chunk_rows,) + (0,) * (ds.ndim - 1)
        info = ds.id.get_chunk_info_by_coord(coords)
        # A byte of the frame's own row: inside the row of a table chunk, the middle of an image's chunk.
        row_bytes = int(np.prod(ds.shape[1:], dtype=np.int64)) * ds.dtype.itemsize
        offset = info.size // 2 if dataset == "images" else (frame % chunk_rows) * row_bytes
        position = info.byte_offset + offset
    with open(path, "r+b") as raw:
        raw.seek(position)
        byte = raw.read(1)
        raw.seek(position)
        raw.write(bytes([byte[0] ^ 0x10]))


def read_everything(path: Path) -> None:
    with open_capture(path) as cap:
        cap.read_images(np.arange(cap.n_frames))
        for column in ("targets", "dedicated", "pose", "time_s", "lap", "car_id"):
            getattr(cap, column)


@pytest.mark.parametrize("dataset", ALL_DATASETS)
def test_a_flipped_byte_in_any_array_is_named(capture_file: Path, dataset: str, fault) -> None:
    read_everything(capture_file)  # the intact file reads
    flip_byte(capture_file, dataset, frame=5)
    with pytest.raises(CaptureFormatError) as info:
        read_everything(capture_file)
    message = str(info.value)
    assert str(capture_file) in message and repr(dataset) in message
    # Images: the exact frame; a table's checksum covers a chunk of rows, named by its frames.
    assert ("frame 5" in message) if dataset == "images" else ("frames 0..15" in message)
    fault.refused(f"one flipped bit in the capture file's {dataset!r} array", message)


def test_the_dataset_refuses_a_damaged_frame_when_training_reads_it(capture_file: Path, fault) -> None:
    from vision_rl.datasets import CaptureDataset

    flip_byte(capture_file, "images", frame=9)
    dataset = CaptureDataset(FrameCatalogue.open(capture_file))
    batch = dataset.__getitems__([0, 1, 2])  # the intact frames are served
    assert batch.images.shape == (3, 16, 24, 3)
    with pytest.raises(CaptureFormatError, match="frame 9") as info:
        dataset.__getitems__([8, 9, 10])
    dataset.close()
    fault.refused("a batch holding a frame whose image bytes were damaged", str(info.value))


def test_a_file_of_format_1_without_checksums_is_refused(capture_file: Path, fault) -> None:
    with h5py.File(capture_file, "r+") as f:
        f.attrs["format_version"] = 1
    with pytest.raises(CaptureFormatError, match="capture it again") as info:
        FrameCatalogue.open(capture_file)
    fault.refused("a capture file of format 1 (no checksums)", str(info.value))


def test_edited_fingerprint_is_refused(capture_file: Path, fault) -> None:
    with h5py.File(capture_file, "r+") as f:
        f.attrs["fingerprint"] = str(f.attrs["fingerprint"]).replace("hatchback", "gt3")
    with pytest.raises(CaptureFormatError, match="fingerprint") as info:
        open_capture(capture_file)
    fault.refused("a capture file whose fingerprint attribute was edited", str(info.value))


def test_content_rewritten_behind_the_checksums_is_refused(capture_file: Path, fault) -> None:
    # h5py recomputes fletcher32 on a write: only the digest recorded at completion notices the new value.
    with h5py.File(capture_file, "r+") as f:
        f["targets"][3, 0] = 1.5
    with pytest.raises(CaptureFormatError, match="content_sha256") as info:
        FrameCatalogue.open(capture_file)
    fault.refused("targets of a completed capture rewritten through HDF5 (valid checksums)", str(info.value))


def test_a_file_cut_short_is_refused(capture_file: Path, tmp_path: Path, fault) -> None:
    cut = tmp_path / "cut.h5"
    data = capture_file.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(CaptureFormatError) as info:
        read_everything(cut)
    assert str(cut) in str(info.value)
    fault.refused("a capture file cut to two thirds of its bytes", str(info.value))


def test_a_damaged_frame_met_in_a_loader_worker_is_one_line(capture_file: Path, fault) -> None:
    # A DataLoader re-raises a worker's error with the worker's traceback as its message: the refusal stays one line.
    from vision_rl.datasets import CaptureDataset

    flip_byte(capture_file, "images", frame=9)
    loader = CaptureDataset(FrameCatalogue.open(capture_file)).loader(batch_size=16, num_workers=1)
    with pytest.raises(CaptureFormatError) as info:
        next(iter(loader))
    message = str(info.value)
    assert len(message.splitlines()) == 1 and "Traceback" not in message, message
    assert str(capture_file) in message and "frame 9" in message
    fault.refused("a damaged frame read by a DataLoader worker process", message)
