"""Command-line options from config dataclasses: one ``--option`` per leaf field, its help from the field's docstring.

A field's help is its attribute docstring (:func:`vision_rl.config.field_docs`), or the word of the config that holds
it; a held config's fields appear flat (:func:`vision_rl.config.flat_fields`). A bool that is off by default becomes
``--x``; one that is on by default becomes ``--no-x`` (and ``--x`` too when the config lists it in
``positive_switches``, a form a command line may state); a config may name extra switches that set a bool to False in
``negative_switches`` (``{"disrupt_ai": "--no-disrupt"}``) or a field's ``metadata={"negative": ...}``. A field with a
fixed set of values names them in ``metadata={"choices": (...)}`` or the config's ``option_choices`` (``{"algo":
ALGOS}``); argparse shows and enforces them. A field whose help ends with "(required)" is required. An empty default
(``""``, None) shows no default text: the help says what empty means.
Field types: int, float, str, bool, ``tuple[int, int]`` (two values after the option, e.g. ``--image-hw-px 140
236``) and ``tuple[int, ...]`` / ``tuple[str, ...]`` (one or more).

Every number is checked here, once for all commands: it must be finite and at least 0, or at least the field's
``metadata={"min": ...}`` / the config's ``option_minimums`` (``{"max_steps": -1}``; ``None``: any sign), and at
most the field's ``metadata={"max": ...}`` where it has one; a duration (a name ending in ``_s``, ``_seconds``,
``_min`` or ``_minutes``) without one is at most :data:`DURATION_MAX_S`. A device other than auto or cpu must be
present. Every size option is priced against the memory budget (:data:`UNIT_BYTES`, frame sizes,
``--hidden-units``); ranges of their own and finer prices are the configs' ``check_options``.
"""

from __future__ import annotations

import argparse
import inspect
import itertools
import math
import os
import re
from collections.abc import Callable
from typing import Any

from vision_rl.budget import DURATION_MAX_S, array_bytes, require_memory
from vision_rl.config import field_docs, flat_fields, from_flat  # noqa: F401  (field_docs: read by the tests here)

_SCALARS = {"int": int, "float": float, "str": str}
_TUPLES = {
    "tuple[int, int]": (int, 2),
    "tuple[float, float]": (float, 2),
    "tuple[int, ...]": (int, "+"),
    "tuple[str, ...]": (str, "+"),
}


def _type_name(annotation: Any) -> str:
    """``"int"``, ``"tuple[int, int]"``... from a string annotation or a type, ``| None`` dropped."""
    name = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", None) or str(annotation)
    return " ".join(name.replace("typing.", "").replace(" | None", "").split())


def _add_bool(parser: argparse.ArgumentParser, flat: Any, help_text: str, config_cls: type) -> None:
    """``--x`` for a bool off by default, ``--no-x`` (and ``--x`` when listed) for one on by default."""
    flag = "--" + flat.name.replace("_", "-")
    if not flat.default:
        parser.add_argument(flag, dest=flat.name, action="store_true", help=help_text)
    else:
        if flat.name in getattr(config_cls, "positive_switches", ()):
            parser.add_argument(flag, dest=flat.name, action="store_true", default=True, help=f"{help_text} (default)")
        no_help = f"off: {help_text[0].lower()}{help_text[1:]} (on by default)" if help_text else None
        parser.add_argument("--no-" + flag[2:], dest=flat.name, action="store_false", default=True, help=no_help)
    negative = dict(getattr(config_cls, "negative_switches", {})).get(flat.name) or flat.field.metadata.get("negative")
    if negative:
        parser.add_argument(negative, dest=flat.name, action="store_false", help=f"same as --no-{flag[2:]}")


_DURATION_SUFFIXES = {"_s": 1.0, "_seconds": 1.0, "_min": 60.0, "_minutes": 60.0}
_NOT_DURATIONS = {"steer_change_penalty_c_s"}  # a weight per second of steering change, c_s


def _maximum(flat: Any) -> float | None:
    """The greatest value of a number option: the field's ``max``, else :data:`DURATION_MAX_S` in the option's unit
    for a duration, else none."""
    if "max" in flat.field.metadata:
        return flat.field.metadata["max"]
    for suffix, unit_s in _DURATION_SUFFIXES.items():
        if flat.name.endswith(suffix) and flat.name not in _NOT_DURATIONS:
            return DURATION_MAX_S / unit_s
    return None


def _minimum(flat: Any, config_cls: type) -> float | None:
    """The least value of a number option: the field's ``min``, else the config's ``option_minimums``, else 0."""
    if "min" in flat.field.metadata:
        return flat.field.metadata["min"]
    return dict(getattr(config_cls, "option_minimums", {})).get(flat.name, 0)


def _number(kind: type, minimum: float | None, maximum: float | None = None) -> Callable[[str], Any]:
    """argparse's ``type=`` for an int or float option: a finite number, at least ``minimum`` (None: any) and at
    most ``maximum`` (None: any)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"{text} is below the least value, {minimum:g}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{text} is above the greatest value, {maximum:g}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse


def _choices(flat: Any, config_cls: type) -> tuple | None:
    named = flat.field.metadata.get("choices") or dict(getattr(config_cls, "option_choices", {})).get(flat.name)
    return tuple(named) if named else None


def _default_text(default: Any) -> str:
    """`` (default: 3)``, or nothing for an empty default (the help says what empty means)."""
    if default is None or default == "" or default == ():
        return ""
    shown = " ".join(map(str, default)) if isinstance(default, tuple) else default
    return f" (default: {shown})"


def add_config_arguments(parser: argparse.ArgumentParser, config_cls: type) -> None:
    """One ``--option`` per leaf field of ``config_cls`` and of the configs it holds (:func:`flat_fields`)."""
    leaves = flat_fields(config_cls)
    flags = {flat.path[-1]: flat.name for flat in leaves} | {flat.name: flat.name for flat in leaves}

    def as_option(match: re.Match) -> str:  # ``laps`` in a docstring reads --laps on the command line
        word = match.group(1)
        return "--" + flags[word].replace("_", "-") if word in flags else word

    for flat in leaves:
        flag = "--" + flat.name.replace("_", "-")
        help_text = re.sub(r"``(\w+)``", as_option, flat.doc).rstrip(".")
        default, kind = flat.default, _type_name(flat.field.type)
        required = help_text.endswith("(required)")
        if kind == "bool":
            _add_bool(parser, flat, help_text, config_cls)
            continue
        if kind not in _SCALARS and kind not in _TUPLES:
            raise TypeError(f"{config_cls.__name__}.{flat.name}: options must be int, float, str, bool or a tuple")
        item, n = (_SCALARS[kind], None) if kind in _SCALARS else _TUPLES[kind]
        if item is not str:
            item = _number(item, _minimum(flat, config_cls), _maximum(flat))
        metavar = ("HEIGHT", "WIDTH") if flat.name.endswith("hw_px") else flat.field.metadata.get("metavar")
        parser.add_argument(
            flag,
            dest=flat.name,
            type=item,
            nargs=n,
            metavar=metavar,
            choices=_choices(flat, config_cls),
            required=required,
            default=None if required else default,
            help=help_text + ("" if required else _default_text(default)),
        )


def config_from_args(config_cls: type, args: argparse.Namespace) -> Any:
    """The config built from parsed options (lists of ``nargs`` options become tuples)."""
    values = {flat.name: getattr(args, flat.name) for flat in flat_fields(config_cls)}
    for name, value in values.items():
        if name == "device" or name.endswith("_device"):
            check_device_present("--" + name.replace("_", "-"), value)
    check_memory(values)
    return from_flat(config_cls, {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def parse_config(config_cls: type, argv: list[str], prog: str | None = None) -> Any:
    """Parse ``argv`` into a ``config_cls``; the parser's description is the class docstring."""
    parser = argparse.ArgumentParser(prog=prog, description=inspect.getdoc(config_cls))
    add_config_arguments(parser, config_cls)
    return config_from_args(config_cls, parser.parse_args(argv))


def check_device_present(option: str, name: str) -> None:
    """Refuse a torch device that is not here (``cuda`` on a machine without a GPU) in one line; ``auto`` and
    ``cpu`` always are, and need no torch."""
    if name in ("auto", "cpu"):
        return
    from vision_rl.phase1_repr.bench import require_device  # torch, only for a device torch has to look for

    try:
        require_device(name)
    except ValueError as exc:
        raise ValueError(str(exc).replace("--device", option, 1)) from None


#: The least a unit of each size option costs in memory, bytes, by flat name: a floor under what the run allocates
#: per unit, so that an absurd size is refused before anything is made. A config's ``check_options`` prices what it
#: knows better (a replay buffer of frames, an encoder's width).
UNIT_BYTES = {
    "cars": 1e6,  # a car's world state, sensors and observation buffers
    "seeds": 1e6,  # seeds drive at once, one car each
    "eval_seeds": 1e6,
    "eval_starts": 1e6,
    "eval_episodes": 1e6,
    "final_eval_episodes": 1e3,
    "runs": 1e3,  # settings' runs or timed calls: a record each
    "setting_runs": 1e3,
    "laps": 1e3,  # a lap's record per car
    "eval_laps": 1e3,
    "reward_laps": 1e3,
    "state_policy_laps": 1e3,
    "workers": 5e8,  # a Ray sampler process with its own simulator and policy
    "num_workers": 2e8,  # a DataLoader worker process and the batches it prefetches
    "seeds_at_once": 1e9,  # a whole train-policy run in its own process
    "devices": 1e9,  # a DDP process per device
    "threads": 8e6,  # a thread's stack
    "torch_threads": 8e6,
    "batch_size": 1e3,  # a sample's inputs, activations and gradients, at the least
    "batch_sizes": 1e3,
    "train_batch_size": 1e3,
    "gail_disc_batch": 1e3,
    "buffer_size": 100,  # a transition: two observations, an action, a reward, a done flag
    "stage3_buffer_size": 100,
    "select_starts": 1e6,  # held-out starts driven at once
    "stats_steps": 1e4,  # a control step's raw observations of every car, kept for the statistics
    "dreamer_sequence_steps": 1e4,  # a step of each sampled sequence: observation, action, latent state
    "frame_delay": 4e5,  # a 280 x 470 RGB frame held per car
}
#: Bytes per pixel of a frame size option, per car: capture's renderer tiles, read-back and queued copies.
PIXEL_BYTES = 32
#: Float32 copies of a batch's frame that a step keeps (input, normalised and augmented frames, first activations).
BATCH_FRAME_FACTOR = 4
#: SAC's networks (actor, two critics, two targets), each with gradients and two Adam moments, float32.
PARAMETER_BYTES = 5 * 4 * 4


def check_memory(values: dict[str, Any]) -> None:
    """Price every size option in ``values`` (flat name -> value) against the memory budget; one line refuses the
    first one over it (:func:`vision_rl.budget.require_memory`)."""
    cars = max([1, *(v for v in (values.get("cars"), values.get("seeds")) if isinstance(v, int))])
    hw_px = values.get("image_hw_px") or (0, 0)
    # A batch of a command with a frame size is a batch of frames: float32 RGB and what a network keeps of them.
    frame_sample_bytes = array_bytes(*hw_px, 3, BATCH_FRAME_FACTOR)
    for name, value in values.items():
        option = "--" + name.replace("_", "-")
        sizes = [v for v in (value if isinstance(value, tuple | list) else [value]) if isinstance(v, int | float)]
        if name == "workers" and values.get("address"):
            continue  # the samplers run on the Ray cluster's machines, not in this one's memory
        if name in UNIT_BYTES and sizes:
            per_unit = UNIT_BYTES[name] * (cars if name == "frame_delay" else 1)
            if "batch" in name:
                per_unit = max(per_unit, frame_sample_bytes)
            require_memory(f"{option} {max(sizes)}", max(sizes) * per_unit)
        elif name.endswith("hw_px") and len(sizes) == 2:
            require_memory(f"{option} {sizes[0]} {sizes[1]}", array_bytes(cars, *sizes, PIXEL_BYTES, itemsize=1))
    if values.get("hidden_units"):
        from vision_rl.training.presets import parse_hidden_units  # light: the presets' parsing, no torch

        widths = parse_hidden_units(values["hidden_units"])
        weights = sum(float(a) * b for a, b in itertools.pairwise(widths)) + 128.0 * sum(widths)
        batch = max(256, int(values.get("batch_size") or 0))
        require_memory(
            f"--hidden-units {values['hidden_units']}",
            weights * PARAMETER_BYTES + array_bytes(batch, sum(widths), 5 * 3),
        )


def comma_list(text: str, kind: Callable[[str], Any] = str) -> list[Any]:
    """The items of a comma-separated option, stripped, empty ones dropped, each through ``kind``."""
    return [kind(part.strip()) for part in text.split(",") if part.strip()]


def comma_paths(text: str) -> list[str]:
    """The paths of a comma-separated option, ``~`` expanded (a shell expands only the first one of such a list)."""
    return comma_list(text, os.path.expanduser)
