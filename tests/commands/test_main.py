"""The dispatcher: the command listing, groups, console-script aliases, one-line errors."""

import json
from pathlib import Path

import pytest

from vision_rl.commands import main as commands_main
from vision_rl.commands.main import COMMANDS, main


def test_tracks_json_lists_the_builtin_and_database_tracks(capsys):
    assert main(["tracks", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows[:3]] == ["expressway", "flowing", "technical"]
    assert len(rows) == 3 + 25 and {r["source"] for r in rows[3:]} == {"racetrack-database"}
    assert all({"name", "length_m", "min_width_m", "corners", "wall_trim_m"} <= set(r) for r in rows)
    by_name = {r["name"]: r for r in rows}
    assert by_name["Catalunya"]["length_m"] == pytest.approx(4641.2, abs=1.0)
    assert by_name["Norisring"]["wall_trim_m"] > 1.0
    assert main(["tracks"]) == 0
    assert "Catalunya     racetrack-database" in capsys.readouterr().out


def test_tracks_check_drives_the_tightest_hairpins(capsys):
    # Norisring and Shanghai: the two circuits whose hairpins are tighter than their inside widths (trimmed walls).
    assert main(["tracks", "--check", "--only", "norisring,SHANGHAI", "--no-progress", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == ["Norisring", "Shanghai"]
    for row in rows:
        assert row["finished"] and row["dnf_reason"] is None, row
        assert row["limit_lap_time_s"] < row["lap_time_s"] < 1.3 * row["limit_lap_time_s"]
        assert row["render_error"] is None or "EGL" in row["render_error"]


def test_tracks_refuses_an_unknown_name_and_bad_laps(capsys):
    assert main(["tracks", "--only", "Catalunia"]) != 0
    assert "--only: unknown track 'Catalunia'" in capsys.readouterr().err
    assert main(["tracks", "--check", "--laps", "0"]) != 0
    assert "--laps must be >= 1, got 0" in capsys.readouterr().err


def test_pipeline_refuses_a_bad_frame_size_and_two_modes(capsys, tmp_path):
    runs = str(tmp_path / "runs")
    assert main(["pipeline", "--tiny", "--runs", runs, "--image-hw-px", "0", "96"]) == 2
    assert "--image-hw-px must be two positive sizes (height, width) or 0 0, got 0 96" in capsys.readouterr().err
    assert main(["pipeline", "--quick", "--tiny", "--runs", runs]) == 2
    assert "--quick and --tiny: choose one" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:  # every number option refuses a negative value as argparse does
        main(["pipeline", "--tiny", "--runs", runs, "--state-policy-laps", "-1"])
    assert stop.value.code == 2
    assert "argument --state-policy-laps: -1 is below the least value, 0" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()  # refused before any stage started


def test_pipeline_refuses_a_kept_encoder_trained_on_other_frames_than_asked(capsys, tmp_path):
    encoder = tmp_path / "runs" / "repr" / "pipeline"
    encoder.mkdir(parents=True)
    (encoder / "ckpt.pt").write_bytes(b"")
    (encoder / "data.json").write_text(json.dumps({"train": [{"file": "train.h5"}]}))
    args = ["pipeline", "--tiny", "--runs", str(tmp_path / "runs")]
    assert main([*args, "--state-policy-laps", "2"]) == 2
    assert "trained without the state policy's laps and --state-policy-laps is 2" in capsys.readouterr().err
    (encoder / "data.json").write_text(json.dumps({"train": [{"file": "train.h5"}, {"file": "state_policy.h5"}]}))
    assert main(args) == 2
    assert "trained with the state policy's laps and --state-policy-laps is 0" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "runs").rglob("*")) == ["ckpt.pt", "data.json", "pipeline", "repr"]


def test_limit_prints_the_lap_time(capsys):
    assert main(["limit", "--track", "technical", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["track"] == "technical" and 60.0 < result["lap_time_s"] < 200.0
    assert main(["limit", "--track", "technical"]) == 0
    assert "lap_time_s: " in capsys.readouterr().out


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([*name.split(), "--help"])
    assert exit_info.value.code == 0
    assert "usage: vision-rl " + name in capsys.readouterr().out


def test_console_script_aliases_run_the_same_commands(monkeypatch, capsys):
    monkeypatch.setattr("sys.argv", ["capture", "--help"])
    with pytest.raises(SystemExit):
        commands_main.capture_main()
    assert "usage: vision-rl capture" in capsys.readouterr().out


def test_unknown_command_fails_in_one_line_with_a_suggestion(capsys):
    assert main(["fly"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'fly'" in err and "--help lists the commands" in err and err.count("\n") == 1
    assert main(["trian-policy"]) == 2
    assert capsys.readouterr().err == "vision-rl: error: unknown command 'trian-policy'; did you mean 'train-policy'?\n"
    assert main(["bench", "rendr"]) == 2
    assert "did you mean 'bench render'?" in capsys.readouterr().err
    assert main(["--help"]) == 0
    assert "bench sim" in capsys.readouterr().out


def test_a_group_word_lists_only_its_commands(capsys):
    assert main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert "bench render" in out and "bench train-repr" in out and "train-policy" not in out
    assert "  bench latency  " in out and "  bench-latency  " not in out  # beside the other benches; the alias stays
    assert COMMANDS["bench latency"].options == COMMANDS["bench-latency"].options
    assert main(["bench"]) == 2
    assert main(["bench", "fly"]) == 2
    assert "unknown command 'bench fly'" in capsys.readouterr().err


def test_bad_input_is_a_one_line_error_not_a_traceback(tmp_path, capsys, monkeypatch):
    bad = tmp_path / "bad.csv"
    bad.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,5,5\n1,0,5,5\n")
    assert main(["bench", "sim", "--track", str(bad), "--repeats", "1"]) == 2
    err = capsys.readouterr().err
    assert "bench sim: error:" in err and "bad.csv" in err
    assert main(["bench", "ddpg", "--device", "gpu"]) == 2
    assert "--device 'gpu' is not a torch device: auto, cpu, cuda or cuda:N" in capsys.readouterr().err
    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    for command in (["bench", "ddpg"], ["bench-latency"], ["bench", "train-repr"]):  # the benchmarks' one check
        assert main([*command, "--device", "cuda"]) == 2
        err = capsys.readouterr().err
        assert "torch sees no CUDA GPU here" in err and "Traceback" not in err, command
    monkeypatch.setenv("VISION_RL_DEBUG", "1")
    with pytest.raises(ValueError):
        main(["limit", "--track", str(bad)])


def test_only_the_emitter_and_the_dispatcher_print():
    # Every command prints through output.emit; the dispatcher prints the listing and one-line errors.
    package = Path(commands_main.__file__).parent
    texts = {p.name: p.read_text() for p in package.glob("*.py")}
    assert sorted(name for name, text in texts.items() if "print(" in text or "json.dumps" in text) == [
        "main.py",
        "output.py",
    ]


def test_an_error_in_a_library_thread_is_one_line(monkeypatch, capsys):
    """TensorBoard's writer thread on a full disk printed its traceback before the command's own line."""
    import errno
    import threading

    from vision_rl.commands import tracks

    def run_with_a_failing_thread(options) -> int:
        def write() -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

        thread = threading.Thread(target=write, name="EventFileWriter")
        thread.start()
        thread.join()
        return 2

    before = threading.excepthook
    monkeypatch.setattr(tracks, "run_tracks", run_with_a_failing_thread)
    assert main(["tracks"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "vision-rl tracks: error in EventFileWriter: OSError: [Errno 28] No space left on device"
    assert threading.excepthook is before  # restored once the command ends
