"""One-line errors for the files users write (scenarios, flight settings): every message names
the file, the field and what to do, e.g. ``cube.toml: planner.dt: must be a positive number of
seconds, got 0``. Unknown keys get a "did you mean"."""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Sequence
from typing import Any, TypeVar

import msgspec
import numpy as np
from numpy.typing import NDArray

from agent.errors import UsageError
from agent.strategy.registry import REGISTRY, StrategyName, strategy_of

Array = NDArray[np.float64]


class ScenarioError(UsageError):
    """A scenario or flight-settings file is missing, malformed or inconsistent; the message
    says where and why."""


_TYPE_WORDS = {
    "float": "a number",
    "int": "an integer",
    "str": "a string",
    "array": "a list",
    "object": "a table",
    "bool": "true or false",
}
_MSGSPEC_RE = re.compile(r"^(?P<msg>.*?)(?: - at `\$(?P<path>[^`]*)`)?$", re.DOTALL)


def _join(prefix: str, path: str) -> str:
    """Field path ``prefix`` + msgspec-style suffix (``.a.b`` or ``[0].c``)."""
    if not prefix:
        return path.lstrip(".")
    if not path:
        return prefix
    return prefix + path if path.startswith("[") else f"{prefix}{path}"


def _words(types: str) -> str:
    parts = [t.strip() for t in types.split("|") if t.strip() != "null"]
    return " or ".join(_TYPE_WORDS.get(t, t) for t in parts)


def validation_message(err: msgspec.ValidationError, prefix: str) -> tuple[str, str]:
    """(field path, what is wrong) from a msgspec validation error."""
    m = _MSGSPEC_RE.match(str(err))
    msg, path = (m.group("msg"), m.group("path") or "") if m else (str(err), "")
    where = _join(prefix, path)
    if mm := re.match(r"Expected `([^`]*)`, got `([^`]*)`", msg):
        return where, f"expected {_words(mm.group(1))}, got {_words(mm.group(2))}"
    if mm := re.match(r"Object missing required field `([^`]*)`", msg):
        field = mm.group(1)
        return _join(where, "." + field), f"required field is missing; add `{field} = ...`"
    return where, msg[:1].lower() + msg[1:]


class Ctx:
    """Collects the source name so every error can be raised in one line."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, what: str) -> ScenarioError:
        where = f"{path}: " if path else ""
        return ScenarioError(f"{self.source}: {where}{what}")


def suggest(word: str, choices: Sequence[str]) -> str:
    """``; did you mean `x`?`` for the closest choice (swapped letters count as closest)."""
    close = [c for c in choices if sorted(c) == sorted(word)]
    close = close or difflib.get_close_matches(word, list(choices), n=1, cutoff=0.5)
    return f"; did you mean `{close[0]}`?" if close else f"; known: {', '.join(choices)}"


def fields_of(t: type[msgspec.Struct]) -> tuple[str, ...]:
    return t.__struct_fields__


def check_keys(ctx: Ctx, raw: Any, t: type[msgspec.Struct], path: str,
                extra: Sequence[str] = ()) -> None:
    """Refuse unknown keys of one table, suggesting the closest known field."""
    if not isinstance(raw, dict):
        return  # msgspec reports the wrong type with the path
    known = (*fields_of(t), *extra)
    for key in raw:
        if key not in known:
            at = f"{path}.{key}" if path else key
            raise ctx.fail(at, f"unknown field{suggest(key, known)}")


_T = TypeVar("_T")


def convert(ctx: Ctx, raw: Any, t: type[_T], prefix: str = "") -> _T:
    try:
        return msgspec.convert(raw, t)
    except msgspec.ValidationError as e:
        where, what = validation_message(e, prefix)
        raise ctx.fail(where, what) from None




def positive(ctx: Ctx, path: str, x: float, unit: str = "") -> float:
    if not (math.isfinite(x) and x > 0):
        raise ctx.fail(path, f"must be a positive number{unit}, got {x}")
    return float(x)


def open_unit(ctx: Ctx, path: str, x: float) -> float:
    if not (0.0 < x < 1.0):
        raise ctx.fail(path, f"must lie strictly between 0 and 1, got {x}")
    return float(x)


def finite(ctx: Ctx, path: str, x: float) -> float:
    if not math.isfinite(x):
        raise ctx.fail(path, f"must be a finite number, got {x}")
    return float(x)


def vector(ctx: Ctx, path: str, x: Sequence[float], dims: int, *, finite: bool = True,
            n: int | None = None) -> Array:
    """``n`` (default ``dims``) numbers, returned as a 3-vector (z = 0 when 2 numbers)."""
    want = dims if n is None else n
    if len(x) != want:
        what = f"a {dims}-D scenario (dims = {dims})" if n is None else "this field"
        raise ctx.fail(path, f"expected {want} numbers for {what}, got {len(x)}")
    a = np.asarray(x, dtype=np.float64)
    if np.isnan(a).any() or (finite and not np.isfinite(a).all()):
        raise ctx.fail(path, f"must contain finite numbers, got {list(x)}")
    return np.append(a, 0.0) if a.size == 2 else a


def nonzero_unit(ctx: Ctx, path: str, a: Array) -> Array:
    n = float(np.linalg.norm(a))
    if n < 1e-12:
        raise ctx.fail(path, "must be a non-zero vector (it is normalised on load)")
    return a / n


def parse_strategy(ctx: Ctx, value: str, trading: bool) -> StrategyName:
    """The ``strategy`` field: a registered one (:mod:`agent.strategy.registry`), with
    trading on if it moves landmarks."""
    name = next((x for x in REGISTRY if x == value), None)
    if name is None:
        raise ctx.fail("strategy", f"unknown strategy {value!r}; use one of "
                       + ", ".join(repr(x) for x in REGISTRY))
    if strategy_of(name).requires_trading and not trading:
        raise ctx.fail("strategy", f"{name!r} moves landmarks between agents; set "
                       "trading = true or use strategy = \"thesis\"")
    return name
