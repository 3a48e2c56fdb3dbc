"""Plain data (parsed YAML) checked against dataclasses: the markers a field's type carries, the
checker that lists every problem at once with its dotted key, and the builder that turns checked
data into the dataclasses' instances (their defaults filled in).

A field's type says what a value may be (``int``, ``float``, ``str``, ``bool``, ``Literal``, a list
or tuple, a ``dict``, another dataclass, a union, ``None``); ``Annotated`` markers add ranges and
vocabularies. A dataclass with a ``problems(self)`` method is asked, once its own fields pass, for
the checks that need more than one field: it returns ``(sub-key, message)`` pairs (``""``: the
entry itself). The configuration's schema (``r2s_eval.schema``) and the world's
(``r2s_eval.sim.world_spec``) are written with these.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Union

from r2s_eval.errors import R2SError

# ----------------------------------------------------------------------------- field markers


@dataclass(frozen=True)
class Range:
    """Numeric bounds; `open_min` / `open_max` exclude the bound itself."""

    min: float | None = None
    max: float | None = None
    open_min: bool = False
    open_max: bool = False

    def problem(self, v: float) -> str | None:
        low = self.min is not None and (v <= self.min if self.open_min else v < self.min)
        high = self.max is not None and (v >= self.max if self.open_max else v > self.max)
        if not (low or high):
            return None
        lo = "-inf" if self.min is None else self.min
        hi = "inf" if self.max is None else self.max
        return f"must be in {'(' if self.open_min else '['}{lo}, {hi}{')' if self.open_max else ']'}, got {v!r}"


@dataclass(frozen=True)
class Finite:
    """A number that is neither infinite nor NaN (YAML's .inf and .nan parse as floats)."""

    def problem(self, v: float) -> str | None:
        return None if math.isfinite(v) else f"must be a finite number, got {v!r}"


@dataclass(frozen=True)
class NonEmpty:
    def problem(self, v: Sequence) -> str | None:
        return "must not be empty" if len(v) == 0 else None


@dataclass(frozen=True)
class Increasing:
    """A [low, high] pair with low <= high."""

    def problem(self, v: Sequence) -> str | None:
        return f"must be [low, high] with low <= high, got {list(v)}" if v[0] > v[1] else None


@dataclass(frozen=True)
class OneOf:
    """A value from a vocabulary its owner defines (loaded when first needed)."""

    values: Callable[[], Sequence[str]]

    def problem(self, v: str) -> str | None:
        known = list(self.values())
        if v in known:
            return None
        close = difflib.get_close_matches(v, known, n=1)
        return f"must be one of {known}, got {v!r}" + (f"; did you mean {close[0]!r}?" if close else "")


@dataclass(frozen=True)
class FieldsOf:
    """Settings that go verbatim to a dataclass of another module: its field names and types."""

    cls: Callable[[], type]


@dataclass(frozen=True)
class Tagged:
    """A mapping whose `key` entry picks the schema of the rest."""

    key: str
    options: dict[str, type]


@dataclass(frozen=True)
class Entries:
    """An open name -> settings map whose entries the owner's validator checks (it raises).

    `schema`, where given, picks the dataclass that types an entry's keys (None: the owner's
    validator alone); an entry whose keys fail it is reported key by key, the owner's
    validator then judging only entries that passed."""

    validate: Callable[[str, dict], Any]
    schema: Callable[[dict], type | None] | None = None


def optional(default_owner: str) -> Any:
    """A key that may be left out; `default_owner` names the code that then supplies its value."""
    return field(default=None, metadata={"default_owner": default_owner})


PositiveInt = Annotated[int, Range(min=1)]
Count = Annotated[int, Range(min=0)]
Positive = Annotated[float, Range(min=0, open_min=True)]
NonNegative = Annotated[float, Range(min=0)]
Share = Annotated[float, Range(0, 1)]
Level = Annotated[float, Range(0, 1, open_min=True, open_max=True)]
Interval = Annotated[tuple[float, float], Increasing()]

# ----------------------------------------------------------------------------- checking


@dataclass
class Problem:
    path: str
    message: str
    unknown: bool = False  # a key the schema does not know (a close known key is suggested)
    owner: bool = False  # the message is an owner's validator's, quoted after a colon


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _describe(value: Any) -> str:
    return f"{value!r} ({type(value).__name__})"


def _split(tp: Any) -> tuple[Any, list[Any]]:
    if typing.get_origin(tp) is Annotated:
        base, *markers = typing.get_args(tp)
        inner, more = _split(base)
        return inner, [*more, *markers]
    return tp, []


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def _check(value: Any, tp: Any, path: str) -> list[Problem]:
    tp, markers = _split(tp)
    if isinstance(value, str) and value == "???":
        return [Problem(path, "has no value (??? in its file); set it, e.g. on the command line")]
    for m in markers:
        if isinstance(m, FieldsOf):
            tp = m.cls()
    tagged = next((m for m in markers if isinstance(m, Tagged)), None)
    if tagged is not None:
        if not isinstance(value, dict):
            return [Problem(path, f"must be a mapping, got {_describe(value)}")]
        tag = value.get(tagged.key)
        if tag not in tagged.options:
            return [Problem(_join(path, tagged.key), f"must be one of {list(tagged.options)}, got {tag!r}")]
        tp = tagged.options[tag]
    problems = _check_type(value, tp, path)
    if problems:
        return problems
    for m in markers:
        if hasattr(m, "problem") and value is not None:
            message = m.problem(value)
            if message:
                problems.append(Problem(path, message))
        elif isinstance(m, Entries):
            for name, entry in value.items():
                problems += _entry_problems(m, path, str(name), entry)
    return problems


def _check_type(value: Any, tp: Any, path: str) -> list[Problem]:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return []
    if origin in (Union, types.UnionType):
        if value is None:
            return [] if type(None) in args else [Problem(path, "must not be null")]
        options = [a for a in args if a is not type(None)]
        results = [_check(value, a, path) for a in options]
        if any(not r for r in results):
            return []
        # The problems of the option the value's shape asks for (a mapping: a dataclass's).
        return next((r for a, r in zip(options, results) if _shaped_like(value, a)), results[0])
    if value is None:
        return [Problem(path, "must not be null")]
    if origin is Literal:
        return [] if value in args else [Problem(path, f"must be one of {list(args)}, got {value!r}")]
    if tp is bool:
        return [] if isinstance(value, bool) else [Problem(path, f"must be true or false, got {_describe(value)}")]
    if tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        return [] if ok else [Problem(path, f"must be an integer, got {_describe(value)}")]
    if tp is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return [] if ok else [Problem(path, f"must be a number, got {_describe(value)}")]
    if tp is str:
        return [] if isinstance(value, str) else [Problem(path, f"must be a string, got {_describe(value)}")]
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            return [Problem(path, f"must be a list, got {_describe(value)}")]
        if origin is tuple and Ellipsis not in args:
            if len(value) != len(args):
                return [Problem(path, f"must be a list of {len(args)} values, got {list(value)}")]
            return [p for i, (v, a) in enumerate(zip(value, args)) for p in _check(v, a, f"{path}[{i}]")]
        item = args[0] if args else Any
        return [p for i, v in enumerate(value) for p in _check(v, item, f"{path}[{i}]")]
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            return [Problem(path, f"must be a mapping, got {_describe(value)}")]
        key_tp, value_tp = args if args else (Any, Any)
        problems = []
        for k, v in value.items():
            key_problems = _check(k, key_tp, _join(path, k))
            problems += [Problem(p.path, f"is not a known name: {p.message}") for p in key_problems]
            if not key_problems:
                problems += _check(v, value_tp, _join(path, k))
        return problems
    if dataclasses.is_dataclass(tp):
        return _check_fields(value, tp, path)
    raise TypeError(f"schema type {tp!r} at {path} is not supported")


def _check_fields(value: Any, cls: type, path: str) -> list[Problem]:
    if not isinstance(value, dict):
        return [Problem(path, f"must be a mapping, got {_describe(value)}")]
    hints, fields = _hints(cls), {f.name: f for f in dataclasses.fields(cls)}
    problems = [Problem(_join(path, k), f"is not a key of {path or 'the config'}", True) for k in value if k not in fields]
    for name, f in fields.items():
        if name not in value:
            required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
            if required:
                problems.append(Problem(_join(path, name), "is missing"))
            continue
        problems += _check(value[name], hints[name], _join(path, name))
    if not problems and hasattr(cls, "problems"):  # the checks that need more than one field
        problems = [Problem(_join(path, key) if key else path, message) for key, message in build(cls, value).problems()]
    return problems


def _shaped_like(value: Any, tp: Any) -> bool:
    tp = _split(tp)[0]
    origin = typing.get_origin(tp)
    if isinstance(value, dict):
        return dataclasses.is_dataclass(tp) or tp is dict or origin is dict
    if isinstance(value, list | tuple):
        return origin in (list, tuple)
    return not (dataclasses.is_dataclass(tp) or origin in (list, tuple, dict) or tp is dict)


def check(value: Any, tp: Any, path: str) -> list[Problem]:
    """Every problem of `value` against the type `tp`, each naming its dotted key under `path`."""
    return _check(value, tp, path)


def build(tp: Any, value: Any) -> Any:
    """The instance of `tp` that checked data `value` describes: dataclasses with their defaults
    filled in, lists as tuples, numbers of a float field as floats."""
    tp = _split(tp)[0]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if value is None:
        return None
    if origin in (Union, types.UnionType):
        option = next(a for a in args if a is not type(None) and not _check(value, a, ""))
        return build(option, value)
    if dataclasses.is_dataclass(tp):
        hints = _hints(tp)
        return tp(**{f.name: build(hints[f.name], value[f.name]) for f in dataclasses.fields(tp) if f.name in value})
    if origin in (list, tuple):
        items = args if origin is tuple and args and Ellipsis not in args else [args[0] if args else Any] * len(value)
        return tuple(build(a, v) for a, v in zip(items, value))
    if origin is dict:
        return {k: build(args[1], v) for k, v in value.items()}
    if tp is float:
        return float(value)
    return value


def _entry_problems(entries: Entries, path: str, name: str, entry: Any) -> list[Problem]:
    where = _join(path, name)
    if not isinstance(entry, dict):
        return [Problem(where, f"must be a mapping of settings, got {_describe(entry)}")]
    schema = entries.schema(entry) if entries.schema else None
    if schema is not None:  # typed keys first; unknown keys are the owner's to explain
        known = {f.name for f in dataclasses.fields(schema)}
        if problems := _check_fields({k: v for k, v in entry.items() if k in known}, schema, where):
            return problems
    try:
        entries.validate(name, entry)
    except (ValueError, TypeError, KeyError, R2SError) as exc:
        message = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
        # Point at the entry's key the validator names first (its messages quote keys as 'key').
        mentioned = [(message.find(f"'{k}'"), k) for k in entry if f"'{k}'" in message]
        key = min(mentioned)[1] if mentioned else None
        return [Problem(_join(where, key) if key else where, message, owner=True)]
    return []
