"""The one emitter of every command's figures, and progress bars (tqdm, on stderr)."""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from vision_rl.files import json_text


def emit(result: Any, as_json: bool, lines: Callable[[Any], list[str]] | None = None) -> None:
    """Print a command's result on stdout: one JSON document, the given text lines, or ``key: value`` rows."""
    if as_json:
        print(json_text(result, indent=2))
    elif lines is not None:
        print("\n".join(lines(result)))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


def number_text(value: float | None, digits: int = 1) -> str:
    """``value`` with ``digits`` decimals, ``-`` for none."""
    return "-" if value is None else f"{value:.{digits}f}"


def note(text: str) -> None:
    """A status line on stderr (what a command is doing, where it writes), apart from its result on stdout."""
    print(text, file=sys.stderr, flush=True)


@contextmanager
def progress_bar(total: int | None, unit: str, desc: str, enabled: bool = True) -> Iterator[Any]:
    """A tqdm bar on stderr (hidden when stderr is not a terminal, or when not ``enabled``)."""
    from tqdm import tqdm

    with tqdm(total=total, unit=unit, desc=desc, disable=None if enabled else True, file=sys.stderr) as bar:
        yield bar


def show(bar: Any, done: int, total: int | None = None, **postfix: Any) -> None:
    """Move ``bar`` to ``done`` (of ``total`` when given) with the figures after it."""
    if total:
        bar.total = total
    bar.n = done
    if postfix:
        bar.set_postfix(postfix, refresh=False)
    bar.update(0)


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def interrupt_on_sigterm() -> Any:
    """Make SIGTERM (a scheduler's stop, ``kill``) interrupt like Ctrl-C, so a trainer saves and exits cleanly (a
    job started in the background of a non-interactive shell ignores SIGINT); returns the handler to restore."""
    return signal.signal(signal.SIGTERM, _raise_interrupt)


def restore_sigterm(previous: Any) -> None:
    signal.signal(signal.SIGTERM, previous)


def format_sampling(sampling: dict[str, Any] | None) -> list[str]:
    """The line of a trainer's result about its sampler actors (none without --workers)."""
    if not sampling:
        return []
    lost = f", {len(sampling['samplers_lost'])} lost" if sampling["samplers_lost"] else ""
    return [
        f"sampling: {sampling['workers']} sampler actors{lost}, {sampling['chunks']} chunks, "
        f"{sampling['weight_versions']} weight versions, staleness at most {sampling['max_staleness_seen']} "
        f"(bound {sampling['max_staleness']}), learner waited {sampling['learner_wait_s']:.0f} s for data"
    ]
