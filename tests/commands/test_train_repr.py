"""`train-repr`: the command trains with its progress bar and prints the kept epoch's figures."""

import json

from tests.datasets.synthetic_capture import write_synthetic_capture
from vision_rl.commands.main import main


def test_train_repr_command_prints_json(tmp_path, capsys):
    data = tmp_path / "d.h5"
    write_synthetic_capture(data, n_laps=4, frames_per_lap=4)
    out = tmp_path / "run"
    argv = ["train-repr", "--data", str(data), "--epochs", "1", "--batch-size", "8", "--num-workers", "0",
            "--width-mult", "0.25", "--val-fraction", "0.25", "--out", str(out), "--progress", "--json"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["ckpt"] == str(out / "ckpt.pt") and result["n_train_frames"] == 12
    assert main(argv) == 2  # the run exists: a one-line error
    assert "--resume" in capsys.readouterr().err
