"""The memory budget: every size a user controls (track extent and resolution, frame size, cars, workers, replay
buffer, network width, batch, seeds) is priced before anything is allocated, and a request over the budget is
refused in one line with its figure and the limit.

The budget is :data:`BUDGET_ENV` in GB when set (``VISION_RL_MEMORY_GB=64``), else :data:`AVAILABLE_SHARE` of the
memory the system can give a new process now. The prices are estimates, generous on purpose: they are there to
refuse the absurd (a 1e12-transition buffer, 100,000 workers) in a second, not to plan a run to the byte.
"""

from __future__ import annotations

import math
import os

#: Environment variable overriding the budget, in GB (docs/guarantees.md).
BUDGET_ENV = "VISION_RL_MEMORY_GB"
#: The longest duration a setting takes, s (a year): longer is no run's length, and 1e308 s overflowed the step
#: counts derived from it (``range(ceil(limit_s / step_s))``: OverflowError tracebacks).
DURATION_MAX_S = 365 * 24 * 3600.0
#: Share of the available memory the budget allows when :data:`BUDGET_ENV` is unset.
AVAILABLE_SHARE = 0.8
#: Assumed when the system does not say (no /proc/meminfo, no sysconf): a small machine.
_UNKNOWN_BYTES = 8 << 30


class MemoryBudgetError(ValueError):
    """A request priced over the memory budget (a ValueError: the command line reports it as one line)."""


def available_memory_bytes() -> int:
    """Memory the system can give a new process (MemAvailable), or the physical memory where that is unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return _UNKNOWN_BYTES


def memory_budget() -> tuple[float, str]:
    """(budget in bytes, where it comes from in words); a bad :data:`BUDGET_ENV` is one line naming it."""
    text = os.environ.get(BUDGET_ENV, "").strip()
    if text:
        try:
            gb = float(text)
        except ValueError:
            gb = math.nan
        if not (math.isfinite(gb) and gb > 0):
            raise ValueError(f"{BUDGET_ENV}={text!r} is not a positive number of GB")
        return gb * 1e9, f"set by {BUDGET_ENV}={text}"
    available = available_memory_bytes()
    share = f"{AVAILABLE_SHARE:.0%} of the {_gb(available)} available"
    return AVAILABLE_SHARE * available, f"{share}; set {BUDGET_ENV} to change it"


def require_memory(what: str, n_bytes: float) -> None:
    """Refuse ``what`` (an option and its value, e.g. ``"--buffer-size 1000000000000"``) when ``n_bytes`` is over
    the budget or not a number; the message gives both figures."""
    limit, source = memory_budget()
    if not n_bytes <= limit:  # NaN is refused too
        raise MemoryBudgetError(
            f"{what} needs about {_gb(n_bytes)} of memory, over the budget of {_gb(limit)} ({source})"
        )


def array_bytes(*dims: float, itemsize: int = 4) -> float:
    """Bytes of an array of shape ``dims`` (a float: sizes of a refused request overflow no integer type)."""
    return float(math.prod(float(d) for d in dims)) * itemsize


def _gb(n_bytes: float) -> str:
    if not math.isfinite(n_bytes):
        return f"{n_bytes} bytes"
    if n_bytes >= 1e12:
        return f"{n_bytes / 1e12:,.1f} TB"
    return f"{n_bytes / 1e9:.1f} GB" if n_bytes >= 1e8 else f"{n_bytes / 1e6:.0f} MB"
