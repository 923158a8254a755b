"""Validation reports: JSON (everything, machine-readable) and JUnit XML (for CI)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, Sequence

from .results import CheckResult, ValidationResult


def summary(results: Sequence[ValidationResult]) -> dict[str, int]:
    """Counts of models, passed and failed."""
    passed = sum(1 for r in results if r.passed)
    accepted = sum(1 for r in results for c in r.checks if c.accepted)
    return {"models": len(results), "passed": passed, "failed": len(results) - passed,
            "acceptedByBaseline": accepted}


def measured_over(c: CheckResult) -> list[tuple[str, float, float]]:
    """(quantity, measured, tolerance) of each quantity of ``c`` over its tolerance."""
    return [(q, v, c.tolerance[q]) for q, v in sorted(c.measured.items())
            if q in c.tolerance and v > c.tolerance[q]]


def failed_checks(results: Sequence[ValidationResult]) -> list[dict[str, Any]]:
    """One entry per failed check: model, check, each quantity's measured value and tolerance, messages."""
    out: list[dict[str, Any]] = []
    for r in results:
        if r.error:
            out.append({"model": r.id, "check": None, "error": r.error})
        for c in r.checks:
            if c.status == "fail":
                out.append({"model": r.id, "check": c.name,
                            "measured": {q: v for q, v, _ in measured_over(c)},
                            "tolerance": {q: t for q, _, t in measured_over(c)}, "messages": c.messages})
    return out


def write_json_report(results: Sequence[ValidationResult], path: Path | str) -> Path:
    """``{"summary": {...}, "failures": [...], "results": [ValidationResult.to_json(), ...]}``;
    ``failures`` names each failed check with its measured values and tolerances."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"summary": summary(results), "failures": failed_checks(results),
           "results": [r.to_json() for r in results]}
    path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    return path


def write_junit_report(results: Sequence[ValidationResult], path: Path | str,
                       suite_name: str = "assetpipe.validate") -> Path:
    """One ``<testsuite>`` per model, one ``<testcase>`` per check (or one ``error`` case).

    Failed checks become ``<failure>`` with their messages; skipped ones ``<skipped>``; an
    asset that could not be validated (crash, timeout) an ``<error>``. Figures go in
    ``<system-out>`` as JSON.
    """
    path = Path(path)
    root = ET.Element("testsuites", name=suite_name)
    total = failures = errors = skipped = 0
    seconds = 0.0
    for r in results:
        suite = ET.SubElement(root, "testsuite", name=r.id or r.model)
        s_fail = s_err = s_skip = 0
        s_time = sum(r.timings.values())
        if r.error:
            case = ET.SubElement(suite, "testcase", classname=r.id, name="validate", time="0")
            ET.SubElement(case, "error", message=r.error[:500]).text = r.error
            s_err += 1
        for c in r.checks:
            case = ET.SubElement(suite, "testcase", classname=r.id, name=c.name, time=f"{c.seconds:.3f}")
            if c.status == "fail":
                over = measured_over(c)
                head = f"{c.name}: " + "; ".join(f"{q} measured {v:g}, tolerance {t:g}" for q, v, t in over)
                text = "\n".join([head] + c.messages) if over else ("\n".join(c.messages) or "failed")
                ET.SubElement(case, "failure", message=text.splitlines()[0][:500],
                              type="check").text = text
                s_fail += 1
            elif c.status == "skip":
                ET.SubElement(case, "skipped", message="; ".join(c.messages)[:500])
                s_skip += 1
            if c.figures:
                ET.SubElement(case, "system-out").text = json.dumps(c.figures)
        n = len(r.checks) + (1 if r.error else 0)
        suite.set("tests", str(n))
        suite.set("failures", str(s_fail))
        suite.set("errors", str(s_err))
        suite.set("skipped", str(s_skip))
        suite.set("time", f"{s_time:.3f}")
        suite.set("file", r.model)
        total += n
        failures += s_fail
        errors += s_err
        skipped += s_skip
        seconds += s_time
    root.set("tests", str(total))
    root.set("failures", str(failures + errors))
    root.set("errors", str(errors))
    root.set("skipped", str(skipped))
    root.set("time", f"{seconds:.3f}")
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    return path
