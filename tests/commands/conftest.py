"""Fixtures of the command tests."""

from tests.phase2_rl.conftest import small_track, state_run  # noqa: F401  (fixtures shared with the Phase-2 tests)
