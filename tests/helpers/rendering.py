"""Whether this machine can render: the tests that draw frames skip with the reason when it cannot."""

from __future__ import annotations


def renderer_available() -> str:
    """Empty if a headless EGL context can be made here, else the reason."""
    try:
        from vision_rl.render import create_context

        create_context().release()
        return ""
    except Exception as exc:  # no EGL library, no driver, no moderngl
        return f"vision_rl.render cannot make an EGL context here: {exc}"
