import json

import pytest

from vision_rl.cli import COMMANDS, main


def test_tracks_json_lists_the_builtin_tracks(capsys):
    assert main(["tracks", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == ["expressway", "flowing", "technical"]
    assert all({"name", "length_m", "min_width_m", "corners"} <= set(r) for r in rows)


@pytest.mark.parametrize("name", list(COMMANDS))
def test_every_command_has_help(name, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([*name.split(), "--help"])
    assert exit_info.value.code == 0
    assert "usage: vision-rl " + name in capsys.readouterr().out


def test_console_script_aliases_run_the_same_commands(monkeypatch, capsys):
    from vision_rl import cli

    monkeypatch.setattr("sys.argv", ["capture", "--help"])
    with pytest.raises(SystemExit):
        cli.capture_main()
    assert "usage: vision-rl capture" in capsys.readouterr().out


def test_unknown_command_fails_with_the_listing(capsys):
    assert main(["fly"]) == 2
    assert "unknown command 'fly'" in capsys.readouterr().err
    assert main(["--help"]) == 0
    assert "bench sim" in capsys.readouterr().out


def test_a_group_word_lists_only_its_commands(capsys):
    assert main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert "bench render" in out and "train-repr" not in out
    assert main(["bench"]) == 2
    assert main(["bench", "fly"]) == 2
    assert "unknown command 'bench fly'" in capsys.readouterr().err


def test_bad_input_is_a_one_line_error_not_a_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,5,5\n1,0,5,5\n")
    assert main(["bench", "sim", "--track", str(bad), "--repeats", "1"]) == 2
    err = capsys.readouterr().err
    assert "bench sim: error:" in err and "bad.csv" in err
