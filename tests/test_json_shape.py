"""Type checks of values read from JSON documents (assetpipe/core/json_shape.py)."""

from __future__ import annotations

from assetpipe.core.json_shape import fields_problem, is_index, is_int, numbers, strings


def test_a_bool_is_no_number_and_null_counts_as_absent():
    assert not is_int(True) and is_int(3) and is_index(0) and not is_index(-1)
    assert numbers([1, 2.5], 2) and not numbers([1, True], 2) and not numbers([1], 2)
    assert numbers([1, None], nulls=True) and not numbers([1, None])
    assert strings([]) and strings(["a"]) and not strings(["a", 1]) and not strings("a")
    assert fields_problem("x", {"a": None, "b": 1}, ints=("a", "b"), strs=("c",)) is None


def test_the_first_value_of_another_type_is_named():
    obj = {"i": 1.5, "k": -1, "n": "1", "s": 2, "v": [1, 2]}
    assert fields_problem("m", obj, ints=("i",)) == "m.i is not an integer"
    assert fields_problem("m", obj, indices=("k",)) == "m.k is not a non-negative integer"
    assert fields_problem("m", obj, nums=("n",)) == "m.n is not a number"
    assert fields_problem("m", obj, strs=("s",)) == "m.s is not a string"
    assert fields_problem("m", obj, vectors=(("v", 3),)) == "m.v is not 3 numbers"
