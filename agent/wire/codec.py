"""Generic msgpack codec for wire messages, built on msgspec.

Wire types are ``msgspec.Struct`` classes (or a tagged union of them, e.g.
``class Pose(msgspec.Struct, tag=True, tag_field="kind")``) that each carry a
``schema: int`` version field, normally with a default (``schema: int = 1``). The default is
the version this build speaks; a received message whose ``schema`` differs is rejected.

:meth:`Codec.decode` never raises: it returns the decoded value, or None after counting the
reason in a :class:`RejectCounter` and logging through a :class:`RateLimitedLogger`.
Reject reasons: ``undecodable`` (not msgpack or does not fit the type), ``schema`` (wrong
version) and ``nonfinite`` (a NaN or infinite float anywhere in the value).
"""

from __future__ import annotations

import logging
import math
import types
import typing
from collections import Counter
from collections.abc import Callable
from typing import Any, Final, Generic, TypeVar

import msgspec

T = TypeVar("T")

REASON_UNDECODABLE: Final = "undecodable"
REASON_SCHEMA: Final = "schema"
REASON_NONFINITE: Final = "nonfinite"
#: Longest piece of network-supplied text (key, detail) written to a log line.
LOG_TEXT_MAX: Final = 120

_log = logging.getLogger(f"viscover.{__name__}")


class RejectCounter:
    """Counts of rejected messages, per reason and per key, for one owner (an agent core,
    stepped by one caller at a time; :class:`agent.net.rejects.LockedRejectCounter` is the
    one shared by transport threads)."""

    def __init__(self) -> None:
        self.by_reason: Counter[str] = Counter()
        self.by_key: Counter[str] = Counter()
        self._total = 0

    def add(self, reason: str, key: str = "") -> None:
        """Count one rejection for ``reason`` received on ``key``."""
        self.by_reason[reason] += 1
        self.by_key[key] += 1
        self._total += 1

    @property
    def total(self) -> int:
        """Number of rejections so far."""
        return self._total

    def snapshot(self) -> dict[str, dict[str, int]]:
        """Copy of the counts: ``{"by_reason": {...}, "by_key": {...}}``."""
        return {"by_reason": dict(self.by_reason), "by_key": dict(self.by_key)}


class RateLimitedLogger:
    """Logs at most one line per reason every ``interval_s`` of ``clock`` (seconds); without a
    clock, the 1st, 10th, 100th... line of each reason (a flood still shows, at a logarithmic
    rate). For one owner; :func:`agent.net.rejects.rate_limited_log` is the wall-clock one
    shared by transport threads.

    Lines suppressed in between are counted and the count is reported on the next line
    emitted for that reason.
    """

    def __init__(
        self,
        logger: logging.Logger | None = None,
        interval_s: float = 10.0,
        level: int = logging.WARNING,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.logger = logger if logger is not None else _log
        self.interval_s = float(interval_s)
        self.level = level
        self._clock = clock
        self._last: dict[str, float] = {}
        self._seen: Counter[str] = Counter()
        self._suppressed: Counter[str] = Counter()

    def _due(self, reason: str) -> bool:
        """Whether a line for ``reason`` may be logged now (and note it)."""
        self._seen[reason] += 1
        if self._clock is None:
            n = self._seen[reason]
            while n % 10 == 0:
                n //= 10
            return n == 1
        now = self._clock()
        last = self._last.get(reason)
        if last is not None and now - last < self.interval_s:
            return False
        self._last[reason] = now
        return True

    def log(self, reason: str, message: str) -> bool:
        """Log ``message`` under ``reason`` unless one was logged too recently.

        Returns True if a line was emitted.
        """
        if not self._due(reason):
            self._suppressed[reason] += 1
            return False
        suppressed = self._suppressed.pop(reason, 0)
        if suppressed:
            since = "" if self._clock is None else f" in the last {self.interval_s:g} s"
            message = f"{message} ({suppressed} similar suppressed{since})"
        self.logger.log(self.level, "%s: %s", reason, message)
        return True


def truncate(text: object, limit: int = LOG_TEXT_MAX) -> str:
    """``text`` as a string of at most ``limit`` characters, marked and sized when cut."""
    s = str(text)
    if len(s) <= limit:
        return s
    return f"{s[:limit]}...(+{len(s) - limit} chars)"


def all_finite(value: Any) -> bool:
    """True if no float inside ``value`` (nested Structs, lists, tuples, dicts, sets, numpy
    arrays) is NaN or infinite."""
    if isinstance(value, float):
        return math.isfinite(value)
    if value is None or isinstance(value, (bool, int, str, bytes, bytearray, memoryview)):
        return True
    if isinstance(value, msgspec.Struct):
        return all(all_finite(getattr(value, f)) for f in value.__struct_fields__)
    if isinstance(value, dict):
        return all(all_finite(k) and all_finite(v) for k, v in value.items())
    if isinstance(value, (list, tuple, set, frozenset)):
        return all(all_finite(v) for v in value)
    dtype = getattr(value, "dtype", None)
    if dtype is not None and getattr(dtype, "kind", "") in "fc":
        import numpy as np

        return bool(np.isfinite(value).all())
    return True


def _struct_types(tp: Any) -> list[type[msgspec.Struct]]:
    """The Struct classes a type annotation names (a Struct or a Union of Structs)."""
    origin = typing.get_origin(tp)
    if origin is typing.Union or isinstance(tp, types.UnionType):
        out: list[type[msgspec.Struct]] = []
        for arg in typing.get_args(tp):
            out.extend(_struct_types(arg))
        return out
    if isinstance(tp, type) and issubclass(tp, msgspec.Struct):
        return [tp]
    return []


def schema_version(cls: type[msgspec.Struct]) -> int | None:
    """Default value of ``cls``'s ``schema`` field, or None if it has none."""
    for field in msgspec.structs.fields(cls):
        if field.name == "schema":
            default = field.default
            return default if isinstance(default, int) else None
    raise TypeError(f"{cls.__name__} has no 'schema: int' field")


class Codec(Generic[T]):
    """Encoder/decoder for one wire type ``T`` (a Struct or a tagged union of Structs).

    Args:
        type_: the wire type.
        schema: expected schema version for every Struct in ``type_``; if None, each Struct's
            ``schema`` field default is used (and must exist).
        counter: where rejections are counted (a new one if None).
        log: rate-limited logger for rejections (a new one with a 10 s interval if None).
    """

    def __init__(
        self,
        type_: Any,
        *,
        schema: int | None = None,
        counter: RejectCounter | None = None,
        log: RateLimitedLogger | None = None,
    ) -> None:
        structs = _struct_types(type_)
        if not structs:
            raise TypeError(f"Codec needs a msgspec.Struct or a Union of them, got {type_!r}")
        self._expected: dict[type, int] = {}
        for cls in structs:
            version = schema if schema is not None else schema_version(cls)
            if version is None:
                raise TypeError(
                    f"{cls.__name__}.schema has no int default; pass Codec(..., schema=N)"
                )
            schema_version(cls)  # asserts the field exists even when schema= is given
            self._expected[cls] = version
        self.type = type_
        self.counter = counter if counter is not None else RejectCounter()
        self.log = log if log is not None else RateLimitedLogger()
        self._encoder = msgspec.msgpack.Encoder()
        self._decoder: msgspec.msgpack.Decoder[T] = msgspec.msgpack.Decoder(type=type_)

    def encode(self, value: T) -> bytes:
        """Serialise ``value`` to msgpack bytes (no checks; the receiver validates)."""
        return self._encoder.encode(value)

    def reject(self, reason: str, key: str, detail: str) -> None:
        """Count and (rate-limited) log one rejected message; key and detail come from the
        network, so both are truncated (:func:`truncate`) before they reach the log."""
        key = truncate(key)
        self.counter.add(reason, key)
        self.log.log(reason, f"rejected message on {key or '<no key>'}: {truncate(detail)}")

    def decode(self, data: bytes | bytearray | memoryview, key: str = "") -> T | None:
        """Decode ``data`` received on ``key``; return None (and count why) if it is rejected."""
        try:
            value = self._decoder.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            self.reject(REASON_UNDECODABLE, key, str(exc))
            return None
        except (TypeError, ValueError) as exc:  # e.g. data is not a bytes-like object
            self.reject(REASON_UNDECODABLE, key, f"{type(exc).__name__}: {exc}")
            return None
        expected = self._expected.get(type(value))
        got = getattr(value, "schema", None)
        if expected is None or got != expected:
            self.reject(REASON_SCHEMA, key, f"schema {got!r}, expected {expected!r}")
            return None
        if not all_finite(value):
            self.reject(REASON_NONFINITE, key, "non-finite float")
            return None
        return value
