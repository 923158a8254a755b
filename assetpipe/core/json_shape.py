"""Type checks of values read from JSON documents the project did not necessarily write (a glTF
file, a state file, a built model's sidecar): each names the first value of another type, so
that the caller reports one line instead of raising where the value is used."""

from __future__ import annotations

from typing import Any


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_index(v: Any) -> bool:
    """A non-negative integer (an index, an offset, a count)."""
    return is_int(v) and v >= 0


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def numbers(v: Any, n: int | None = None, nulls: bool = False) -> bool:
    """A list of numbers (``n`` of them, when given; null items too with ``nulls``)."""
    return isinstance(v, list) and (n is None or len(v) == n) and all(
        is_number(x) or (nulls and x is None) for x in v)


def strings(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(x, str) for x in v)


def objects(v: Any) -> bool:
    return isinstance(v, list) and all(isinstance(x, dict) for x in v)


def fields_problem(where: str, obj: dict, ints=(), indices=(), nums=(), strs=(), vectors=()) -> str | None:
    """The first key of ``obj`` whose value has another type than named (null counts as absent):
    ``ints``, ``indices`` (non-negative integers), ``nums``, ``strs``: names; ``vectors``:
    (name, length) pairs of number lists. None when every one has its type."""
    for keys, ok, what in ((ints, is_int, "an integer"), (indices, is_index, "a non-negative integer"),
                           (nums, is_number, "a number"), (strs, lambda v: isinstance(v, str), "a string")):
        for key in keys:
            if obj.get(key) is not None and not ok(obj[key]):
                return f"{where}.{key} is not {what}"
    for key, length in vectors:
        if obj.get(key) is not None and not numbers(obj[key], length):
            return f"{where}.{key} is not {length} numbers"
    return None
