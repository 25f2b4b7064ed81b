"""`train-repr`: the command trains with its progress bar and prints the kept epoch's figures."""

import json

from tests.helpers.captures import write_synthetic_capture
from vision_rl.commands.main import main


def test_train_repr_command_prints_json(tmp_path, capsys):
    data = tmp_path / "d.h5"
    write_synthetic_capture(data, n_laps=4, frames_per_lap=4)
    out = tmp_path / "run"
    argv = [
        "train-repr",
        "--data",
        str(data),
        "--epochs",
        "1",
        "--batch-size",
        "8",
        "--num-workers",
        "0",
        "--width-mult",
        "0.25",
        "--val-fraction",
        "0.25",
        "--out",
        str(out),
        "--json",
    ]
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ckpt"] == str(out / "ckpt.pt") and result["n_train_frames"] == 12
    assert main(argv) == 2  # the run exists: a one-line error
    assert "--resume" in capsys.readouterr().err


def test_the_summary_never_says_kept_epoch_none_nor_prints_missing_paths(tmp_path):
    from vision_rl.commands.train_repr import format_train_repr

    metrics = tmp_path / "metrics.json"
    metrics.write_text("{}")
    result = {
        "ckpt": str(tmp_path / "ckpt.pt"),
        "metrics_json": str(metrics),
        "figure": str(tmp_path / "no.png"),
        "tensorboard": None,
        "n_train_frames": 12,
        "n_val_frames": 4,
        "best_epoch": None,
        "val_loss": None,
        "val_r2": None,
    }
    text = "\n".join(format_train_repr(result))
    assert "None" not in text and "kept the last weights" in text
    assert str(metrics) in text and "no.png" not in text and "TensorBoard" not in text
    text = "\n".join(format_train_repr({**result, "best_epoch": 3, "val_loss": 0.12345}))
    assert "kept epoch 3 (val loss 0.1235)" in text
