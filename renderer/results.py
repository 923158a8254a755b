"""The types every check, runner and report shares: options, one check's result, one model's result.

A :class:`CheckResult` carries, besides its messages and figures, ``measured`` and
``tolerance``: for each quantity the check compares (``"colorDiff"``, ``"blackLevels"``...),
the worst value measured and the limit it was held to. Reports print them; a baseline
(:mod:`renderer.baseline`) accepts a failed check when every measured quantity stays within
the values recorded for that model and check.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from assetpipe.core.json_shape import is_int

from .camera import DEFAULT_VIEW

#: the largest render target side (pixels) the offscreen renderer makes
MAX_RENDER_SIZE = 16384
#: the smallest side (pixels) a validation renders at. The picture checks forgive a pixel, so
#: below some size they pass what is plainly wrong: the validate fixtures (pbr, mask, multiuv,
#: orm) with every vertex moved 10% of the way to the box centre passed every check at 4 px
#: and failed the source check from 8 px on (shrunk 30%: from 4 px on; 3%: at 8 and 16 px,
#: not 12). 16 is twice the smallest size that caught the 10% shrink on each of them
#: (tests/test_validate_mutations.py holds it at this size).
MIN_VALIDATE_SIZE = 16

DEFAULT_VIEWS: tuple[tuple[float, float, float], ...] = (DEFAULT_VIEW, (0.8, -0.3, 0.7), (0.2, -1.0, 0.3))


@dataclass(frozen=True)
class ValidateOptions:
    """Options of the checks; every figure the checks compare against is here (each check's
    module says why its value is right)."""

    width: int = 256
    height: int = 256
    views: tuple[tuple[float, float, float], ...] = DEFAULT_VIEWS
    checks: tuple[str, ...] = ()  # empty: every registered check
    validation_layer: bool = True
    bbox_tolerance_px: float = 2.0
    # a silhouette or LOD comparison that fails is rendered again at this many times the pixels a
    # side, the same picture sampled finer, and judged in the same pixel units: geometry thinner
    # than a pixel (wires, antennae) covers pixel centres only here and there, so its picture at
    # one sample a pixel is dotted and the dots fall differently for LOD0 and LOD k, or miss a
    # thin extreme by more than a pixel (renderer/checks/silhouette.py, lods.py). 1: no second look
    supersample: int = 4
    source_root: str | None = None  # where to look for the sources (searched recursively)
    source_max_xor: float = 0.03
    source_max_unexplained: float = 0.002
    # mean 8x8-block colour difference, build against source (renderer/checks/source.py says why);
    # plus texture_compressed_png_tolerance - texture_png_tolerance when a drawn texture is block-compressed
    source_color_tolerance: float = 2.0 / 255.0
    lod_reference_px: int = 1080
    lod_reference_fov_deg: float = 60.0
    lod_max_render_px: int = 512
    lod_max_unexplained_px: int = 4
    lod_max_unexplained_fraction: float = 0.002
    texture_mean_tolerance: float = 0.12
    texture_png_tolerance: float = 2.0 / 255.0
    # compressed level 0 vs the image: 2/255 as above plus 4/255, the RMS error of the 36 dB PSNR
    # goal of the block encoders (a mean absolute error is at most the RMS error)
    texture_compressed_png_tolerance: float = 6.0 / 255.0
    texture_sample_px: int = 256  # image comparisons look at level 0 sampled to at most this size
    role_tolerance: float = 2.0 / 255.0  # renderer/checks/roles.py says why (at its 256 px comparison level)
    timeout_s: float = 120.0
    shader_cache: str | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if not is_int(v) or not MIN_VALIDATE_SIZE <= v <= MAX_RENDER_SIZE:
                raise ValueError(f"ValidateOptions.{name} must be an integer from {MIN_VALIDATE_SIZE} to "
                                 f"{MAX_RENDER_SIZE} pixels (smaller pictures pass what is plainly wrong), got {v!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ValidateOptions":
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in data.items() if k in names}
        if "views" in kw:
            kw["views"] = tuple(tuple(float(c) for c in v) for v in kw["views"])
        if "checks" in kw:
            kw["checks"] = tuple(kw["checks"])
        return cls(**kw)


@dataclass
class CheckResult:
    """One check: ``status`` is "pass", "fail" or "skip"; ``figures`` are its measurements,
    ``measured``/``tolerance`` the worst value of each compared quantity and its limit."""

    name: str
    status: str
    figures: dict[str, Any] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    seconds: float = 0.0
    measured: dict[str, float] = field(default_factory=dict)
    tolerance: dict[str, float] = field(default_factory=dict)
    accepted: str | None = None  # set when a baseline accepted this failure (the reason)

    @property
    def passed(self) -> bool:
        return self.status != "fail"

    def worst(self, quantity: str, value: float, limit: float) -> bool:
        """Record ``value`` of ``quantity`` (keeping the largest) against ``limit``; True when over."""
        value = float(value)
        if quantity not in self.measured or value > self.measured[quantity]:
            self.measured[quantity] = value
        self.tolerance[quantity] = float(limit)
        return value > limit

    def finish(self) -> "CheckResult":
        """Set the status from the messages (fail when any) unless skipped; round figures."""
        if self.status != "skip":
            self.status = "fail" if self.messages else "pass"
        self.figures = jsonable(self.figures)
        self.measured = {k: round(v, 6) for k, v in self.measured.items()}
        return self


@dataclass
class ValidationResult:
    """All checks of one model, the notes, and the time split (setup/load/upload/render/compare)."""

    model: str
    id: str
    checks: list[CheckResult] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    error: str | None = None  # set when the asset could not be validated at all (crash, timeout)

    @property
    def passed(self) -> bool:
        return self.error is None and all(c.passed for c in self.checks)

    def check(self, name: str) -> CheckResult | None:
        return next((c for c in self.checks if c.name == name), None)

    def failures(self) -> list[str]:
        """One line per failed check (or the error)."""
        out = [f"{self.model}: {self.error}"] if self.error else []
        out += [f"{self.model}: {c.name}: {'; '.join(c.messages) or 'failed'}" for c in self.checks if not c.passed]
        return out

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["passed"] = self.passed
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ValidationResult":
        names = {f.name for f in fields(CheckResult)}
        checks = [CheckResult(**{k: v for k, v in c.items() if k in names}) for c in d.get("checks", [])]
        return cls(model=d["model"], id=d.get("id", ""), checks=checks, notes=list(d.get("notes", [])),
                   timings=dict(d.get("timings", {})), error=d.get("error"))


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars made Python and non-finite floats made strings."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x
