"""Configs that compose: a trainer's frozen config holds its environment's config and its schedules as fields.

The command line and a search over options see such a tree flat, one name per leaf field (``--cars`` for
``racing.n_groups``): :func:`flat_fields` lists them, :func:`from_flat` and :func:`replace_flat` build configs from
flat names. A field's help is its attribute docstring (:func:`field_docs`), or the holder's word for it; a config
with a ``check_options(flat_values)`` static method has the flat values checked before anything is built,
typically with :func:`check_option_bounds`.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import math
import textwrap
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Nesting:
    """How a held config's fields appear flat: ``prefix + name`` or ``rename[name]``, only those in ``only`` (all
    when None), with ``help[name]`` in place of a field's own docstring where the holder says it better."""

    prefix: str = ""
    only: tuple[str, ...] | None = None
    rename: Mapping[str, str] = field(default_factory=dict)
    help: Mapping[str, str] = field(default_factory=dict)


def nested(
    default: Any,
    *,
    prefix: str = "",
    only: tuple[str, ...] | None = None,
    rename: Mapping[str, str] | None = None,
    help: Mapping[str, str] | None = None,
) -> Any:
    """A dataclass field holding the config ``default`` (a frozen instance), seen flat as :class:`Nesting` says."""
    spec = Nesting(prefix, only, dict(rename or {}), dict(help or {}))
    return field(default_factory=lambda: default, metadata={"nested": spec})


def field_docs(config_cls: type) -> dict[str, str]:
    """Field name -> attribute docstring (one line), over the class and its dataclass bases (the subclass wins)."""
    return dict(_field_docs(config_cls))


@functools.cache  # a class's source does not change while it is loaded; parsing it is most of a command's parse
def _field_docs(config_cls: type) -> dict[str, str]:
    docs: dict[str, str] = {}
    for klass in reversed(config_cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):  # no source (built at run time): metadata help only
            continue
        node = tree.body[0]
        if not isinstance(node, ast.ClassDef):
            continue
        for stmt, after in zip(node.body, node.body[1:], strict=False):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[stmt.target.id] = " ".join(after.value.value.split())
    return docs


@dataclass(frozen=True)
class FlatField:
    """One leaf field of a config tree, under its flat name."""

    name: str
    """The flat name (an option's name with underscores)."""
    path: tuple[str, ...]
    """Attribute names from the top config down to the field."""
    field: dataclasses.Field
    doc: str
    """Its help line: the holder's word, else the field's docstring, else ``metadata["help"]``."""
    default: Any


def _nesting(f: dataclasses.Field) -> Nesting | None:
    return f.metadata.get("nested")


def flat_fields(config_cls: type) -> list[FlatField]:
    """Every leaf field of ``config_cls`` and of the configs it holds, in declaration order."""
    return list(_flat_fields(config_cls))


@functools.cache
def _flat_fields(config_cls: type) -> tuple[FlatField, ...]:
    out: list[FlatField] = []
    docs = field_docs(config_cls)
    defaults = _defaults(config_cls)
    for f in dataclasses.fields(config_cls):
        spec = _nesting(f)
        if spec is None:
            out.append(
                FlatField(f.name, (f.name,), f, docs.get(f.name) or f.metadata.get("help", ""), defaults[f.name])
            )
            continue
        held = defaults[f.name]
        for inner in flat_fields(type(held)):
            top = inner.path[0]
            if spec.only is not None and top not in spec.only:
                continue
            name = spec.rename.get(top, spec.prefix + inner.name)
            doc = spec.help.get(top, inner.doc)
            default = held
            for attribute in inner.path:
                default = getattr(default, attribute)
            out.append(FlatField(name, (f.name, *inner.path), inner.field, doc, default))
    names = [flat.name for flat in out]
    if len(set(names)) != len(names):
        raise TypeError(f"{config_cls.__name__}: flat names repeat: {sorted(n for n in names if names.count(n) > 1)}")
    return tuple(out)


def _defaults(config_cls: type) -> dict[str, Any]:
    out = {}
    for f in dataclasses.fields(config_cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
        else:
            out[f.name] = None
    return out


def flat_values(config: Any) -> dict[str, Any]:
    """Flat name -> value of every leaf field of ``config``."""
    values = {}
    for flat in flat_fields(type(config)):
        value = config
        for name in flat.path:
            value = getattr(value, name)
        values[flat.name] = value
    return values


def resume_conflicts(config: Any, kept: Mapping[str, Any], names: Iterable[str]) -> list[str]:
    """The options among ``names`` that ``config`` sets away from their defaults and from a resumed run's own value
    (``kept``: flat name -> value, as JSON holds it): a resumed run keeps its own, so each would be ignored without a
    word. An option typed at its default value cannot be told from one left out; it is not reported."""
    now = flat_values(config)
    defaults = {flat.name: flat.default for flat in flat_fields(type(config))}

    def same(a: Any, b: Any) -> bool:
        return (tuple(a) if isinstance(a, list) else a) == (tuple(b) if isinstance(b, list) else b)

    return [
        f"--{name.replace('_', '-')} {now[name]!r} (the run's: {kept[name]!r})"
        for name in names
        if name in kept and not same(now[name], defaults[name]) and not same(now[name], kept[name])
    ]


def replace_flat(config: Any, **values: Any) -> Any:
    """``config`` with the leaf fields named flat in ``values`` replaced; an unknown name is a TypeError."""
    by_name = {flat.name: flat.path for flat in flat_fields(type(config))}
    unknown = sorted(set(values) - set(by_name))
    if unknown:
        raise TypeError(f"{type(config).__name__} has no field {', '.join(unknown)}")
    check = getattr(type(config), "check_options", None)
    if check is not None:  # in the options' own words, before a held config refuses a value in its own
        check({**flat_values(config), **values})
    tree: dict[str, Any] = {}
    for name, value in values.items():
        node = tree
        *heads, last = by_name[name]
        for head in heads:
            node = node.setdefault(head, {})
        node[last] = value
    return _replace_tree(config, tree)


def _replace_tree(config: Any, tree: Mapping[str, Any]) -> Any:
    changes = {
        name: _replace_tree(getattr(config, name), sub) if isinstance(sub, dict) else sub for name, sub in tree.items()
    }
    return dataclasses.replace(config, **changes)


def from_flat(config_cls: type, values: Mapping[str, Any] | None = None, **more: Any) -> Any:
    """A ``config_cls`` of its defaults with the leaf fields named flat in ``values`` and ``more`` replaced."""
    defaults = config_cls(**_defaults(config_cls))
    return replace_flat(defaults, **{**(values or {}), **more})


@dataclass(frozen=True)
class Bounds:
    """The values a number option may take: from ``low`` to ``high``, each end included unless it is open. NaN is
    in no bounds."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    def __contains__(self, value: float) -> bool:
        above_low = value > self.low if self.low_open else value >= self.low
        below_high = value < self.high if self.high_open else value <= self.high
        return above_low and below_high

    def __str__(self) -> str:
        ends = []
        if self.low > -math.inf:
            ends.append(f"{'more than' if self.low_open else 'at least'} {self.low:g}")
        if self.high < math.inf:
            ends.append(f"{'less than' if self.high_open else 'at most'} {self.high:g}")
        return " and ".join(ends) or "any number"


def at_least(low: float) -> Bounds:
    return Bounds(low)


def above(low: float) -> Bounds:
    return Bounds(low, low_open=True)


def check_option_bounds(values: Mapping[str, Any], bounds: Mapping[str, Bounds]) -> None:
    """Raise ValueError naming the first option (flat name) whose value in ``values`` is outside its ``bounds``,
    with the range it may take: ``--laps 0 is out of range: at least 1``."""
    for name, allowed in bounds.items():
        if values[name] not in allowed:
            raise ValueError(f"--{name.replace('_', '-')} {values[name]} is out of range: {allowed}")
