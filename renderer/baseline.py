"""Baselines: known differences a project accepts, per model and check.

A baseline file is JSON::

    {"baselineVersion": 1,
     "models": {"<model id>": {"<check name>": {"<quantity>": <accepted worst value>, ...}}}}

A failed check of a listed model is *accepted* (status "pass", ``accepted`` says why) when every
quantity it measured over its tolerance is listed and stays at or below the accepted value
(plus 1% of it, for run-to-run float noise). A worse value, or a quantity not listed, still fails,
so a CI goes green on known differences and still catches regressions. ``write_baseline``
records every failed check of a run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from assetpipe.core.errors import AssetpipeError

from .results import ValidationResult

SLACK = 0.01


def load_baseline(path: Path | str) -> dict[str, dict[str, dict[str, float]]]:
    """The ``models`` mapping of a baseline file (raises AssetpipeError on a malformed file)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        models = doc["models"]
        assert isinstance(models, dict)
        return {str(m): {str(c): {str(q): float(v) for q, v in qs.items()} for c, qs in checks.items()}
                for m, checks in models.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, AssertionError) as exc:
        raise AssetpipeError(f"{path}: not a baseline file ({type(exc).__name__}: {exc})") from None


def apply_baseline(result: ValidationResult, baseline: dict[str, dict[str, dict[str, float]]]) -> ValidationResult:
    """Mark the failed checks of ``result`` the baseline accepts (in place; returns ``result``)."""
    accepted = baseline.get(result.id) or {}
    for c in result.checks:
        if c.status != "fail" or c.name not in accepted:
            continue
        over = {q: v for q, v in c.measured.items() if v > c.tolerance.get(q, float("inf"))}
        allowed = accepted[c.name]
        if over and all(q in allowed and v <= allowed[q] + SLACK * abs(allowed[q]) for q, v in over.items()):
            c.status = "pass"
            c.accepted = "accepted by the baseline: " + ", ".join(
                f"{q} {v:g} <= {allowed[q]:g}" for q, v in sorted(over.items()))
            c.messages = [c.accepted] + [f"(known) {m}" for m in c.messages]
    return result


def baseline_of(results: Sequence[ValidationResult]) -> dict[str, Any]:
    """A baseline accepting every failed check of ``results`` at its measured values."""
    models: dict[str, dict[str, dict[str, float]]] = {}
    for r in results:
        for c in r.checks:
            if c.status == "fail":
                over = {q: v for q, v in c.measured.items() if v > c.tolerance.get(q, float("inf"))}
                if over:
                    models.setdefault(r.id, {})[c.name] = over
    return {"baselineVersion": 1, "models": models}


def write_baseline(results: Sequence[ValidationResult], path: Path | str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(baseline_of(results), indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path
