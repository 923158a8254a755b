"""Command-line parameter types shared by the commands of every layer (the build's, the
renderer's)."""

from __future__ import annotations

import math

import click


class FiniteFloatRange(click.FloatRange):
    """A float range that refuses NaN and infinity (``inf`` passes a range with no upper end, and
    NaN compares false with either end): a budget, size or time must be a number."""

    name = "finite float range"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{rv} is not a finite number", param, ctx)
        return rv
