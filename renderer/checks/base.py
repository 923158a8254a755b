"""The one interface every check speaks: a name, what it measures, its tolerance and why.

A check is a :class:`Check` subclass with those four class attributes and :meth:`Check.run`,
which reads what it needs from a :class:`Context` (the model, the renders already made, the
renderer) and returns a :class:`~renderer.results.CheckResult` under its name. The runner
(:func:`renderer.validate.run_checks`) iterates over :data:`renderer.checks.REGISTRY`; a
report, a baseline and ``--checks`` all name checks by ``Check.name``.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..camera import Camera
from ..loader import RenderModel
from ..results import CheckResult, ValidateOptions


class Timer:
    """Adds the time spent in a ``with`` block to ``timings[key]`` when the block runs on the
    thread ``owner`` (the one running the model's checks). A check running on a thread beside
    it (:attr:`Check.beside`) is not split into phases: its wall time is its result's
    ``seconds``, and the owner's wait for it counts as ``compare``; so the phases still add
    up to the model's time."""

    def __init__(self, timings: dict[str, float], key: str, owner: int | None = None) -> None:
        self.timings, self.key, self.owner = timings, key, owner

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        if self.owner is not None and threading.get_ident() != self.owner:
            return
        self.timings[self.key] = self.timings.get(self.key, 0.0) + time.perf_counter() - self.t0


@dataclass
class Context:
    """What one model's checks share. ``model`` is None when the built files did not load;
    ``gpu``/``cams``/``coverage``/``shaded`` are filled by the runner before render checks run."""

    model_json: Path
    options: ValidateOptions
    renderer: Any
    timings: dict[str, float]
    notes: list[str]
    model: RenderModel | None = None
    load_error: str | None = None
    gpu: Any = None
    cams: list[Camera] = field(default_factory=list)
    coverage: list[np.ndarray] = field(default_factory=list)   # per view, bool (H, W), no culling
    front: list[np.ndarray] = field(default_factory=list)      # per view, bool: nearest surface faces the eye
    shaded: list[np.ndarray] = field(default_factory=list)     # per view, RGBA uint8
    cache: dict[str, Any] = field(default_factory=dict)
    owner: int = field(default_factory=threading.get_ident)  # the thread whose timers count

    def timer(self, key: str) -> Timer:
        return Timer(self.timings, key, self.owner)


class Check:
    """Base of every check: set the four attributes, implement :meth:`run`."""

    name: ClassVar[str] = ""
    measures: ClassVar[str] = ""   # what is compared, in one sentence
    tolerance: ClassVar[str] = ""  # the limit(s), naming the ValidateOptions fields
    reason: ClassVar[str] = ""     # why the limit is right (derived from the data)
    needs_render: ClassVar[bool] = False  # needs the uploaded model and the per-view renders
    # reads only files (the built model's and the source's bytes through the per-model cache,
    # whose decodes are locked per image): runs on a thread beside the other checks, so that
    # its image reductions overlap the renders' comparisons and the source model's reading
    beside: ClassVar[bool] = False

    def run(self, ctx: Context) -> CheckResult:  # pragma: no cover - abstract
        raise NotImplementedError

    def result(self) -> CheckResult:
        return CheckResult(self.name, "pass")

    def describe(self) -> dict[str, str]:
        return {"name": self.name, "measures": self.measures, "tolerance": self.tolerance, "reason": self.reason}
