"""The memory budget: where its limit comes from, and what it refuses."""

from __future__ import annotations

import math

import pytest

from vision_rl.budget import (
    AVAILABLE_SHARE,
    BUDGET_ENV,
    MemoryBudgetError,
    array_bytes,
    available_memory_bytes,
    memory_budget,
    require_memory,
)


def test_the_budget_is_a_share_of_the_available_memory_unless_the_environment_gives_one(monkeypatch):
    monkeypatch.delenv(BUDGET_ENV, raising=False)
    limit, source = memory_budget()
    assert 0 < limit <= AVAILABLE_SHARE * available_memory_bytes() * 1.05  # the available memory moves a little
    assert BUDGET_ENV in source and "available" in source
    monkeypatch.setenv(BUDGET_ENV, "2.5")
    assert memory_budget() == (2.5e9, f"set by {BUDGET_ENV}=2.5")
    for bad in ("0", "-1", "nan", "inf", "lots"):
        monkeypatch.setenv(BUDGET_ENV, bad)
        with pytest.raises(ValueError, match=f"^{BUDGET_ENV}='{bad}' is not a positive number of GB$"):
            memory_budget()


def test_a_request_over_the_budget_is_refused_with_both_figures(monkeypatch):
    monkeypatch.setenv(BUDGET_ENV, "1")
    require_memory("--cars 10", 0.99e9)
    with pytest.raises(MemoryBudgetError) as refused:
        require_memory("--cars 1000", 2.5e9)
    assert str(refused.value) == (
        f"--cars 1000 needs about 2.5 GB of memory, over the budget of 1.0 GB (set by {BUDGET_ENV}=1)"
    )
    assert isinstance(refused.value, ValueError)  # the command line reports it as one line
    for absurd in (math.inf, math.nan, array_bytes(10**12, 10**12, 3)):
        with pytest.raises(MemoryBudgetError):
            require_memory("--x", absurd)


def test_array_sizes_do_not_overflow():
    assert array_bytes(2, 3, itemsize=8) == 48.0
    assert array_bytes(10**20, 10**20) == 4e40  # a float: no int64 wraps a refused request round to a small one
