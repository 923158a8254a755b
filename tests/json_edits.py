"""JSON documents edited one value at a time: the tests that replace every value of a sound
document by values of other types (the importers, inspect, the validator) and the fuzzer."""

from __future__ import annotations

import copy
from typing import Any, Iterator


def value_paths(doc: Any, first: int | None = None, prefix: tuple = ()) -> Iterator[tuple]:
    """Every (key or index) path to a value in ``doc``, depth-first; ``first``: at most that many
    items of each list (None: all)."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield prefix + (k,)
            yield from value_paths(v, first, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc if first is None else doc[:first]):
            yield prefix + (i,)
            yield from value_paths(v, first, prefix + (i,))


def with_value(doc: Any, path: tuple, value: Any) -> Any:
    """A deep copy of ``doc`` with the value at ``path`` replaced by (a copy of) ``value``."""
    out = copy.deepcopy(doc)
    parent = out
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = copy.deepcopy(value)
    return out
