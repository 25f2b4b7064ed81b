"""`play` faults: no display, no gamepad, a bad alias, and the player quitting midway (the drive is kept)."""

from __future__ import annotations

import pytest

from vision_rl.evaluation.human import NoDisplayError
from vision_rl.overtaking.config import PlayConfig
from vision_rl.overtaking.play import play

pygame = pytest.importorskip("pygame", reason="pygame is not installed: pip install 'vision_rl[play]'")


def test_no_display(fault, monkeypatch):
    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(NoDisplayError) as excinfo:
        play(PlayConfig(name="someone", track="technical", realtime=False))
    fault.refused("play on a machine without a display", str(excinfo.value))


def test_no_gamepad(fault, monkeypatch, gl_available):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    with pytest.raises(NoDisplayError) as excinfo:
        play(PlayConfig(name="someone", track="technical", input="gamepad", realtime=False, window_hw_px=(64, 96)))
    assert "no gamepad" in str(excinfo.value)
    fault.refused("play --input gamepad with no gamepad connected", str(excinfo.value))


def test_bad_alias(fault):
    with pytest.raises(ValueError) as excinfo:
        play(PlayConfig(name="a b", realtime=False))
    fault.refused("play --name with a space", str(excinfo.value))


def test_player_quits_midway(fault, monkeypatch, tmp_path, gl_available):
    from vision_rl.overtaking.demos import load_demos

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame.init()
    script = iter(
        [[pygame.event.Event(pygame.KEYDOWN, key=pygame.K_UP)]]
        + [[]] * 40
        + [[pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE)]]
    )
    result = play(
        PlayConfig(
            name="quitter", track="technical", realtime=False, window_hw_px=(64, 96), runs=str(tmp_path / "runs")
        ),
        events=lambda: next(script, []),
    )
    assert result["quit"] and not (tmp_path / "runs/human/quitter-technical-hatchback/evaluation.json").exists()
    demos = load_demos(result["demos"])
    assert demos.n_transitions == 8  # 41 calls at 50 Hz: 9 commands, the last one's step unfinished
    fault.recovered(
        "the player pressed Escape after 0.8 s",
        f"no row; the {demos.n_transitions} transitions driven were kept as demonstrations",
    )
