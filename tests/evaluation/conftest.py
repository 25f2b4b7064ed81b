"""The small stadium track of the Phase-2 tests."""

from tests.phase2_rl.conftest import small_track  # noqa: F401  (a fixture shared with the Phase-2 tests)
