"""What a build prints: a line per asset (or a rich progress bar on a terminal), the reasons
with --explain, and a summary line with the counts."""

from __future__ import annotations

import sys

import click


class Reporter:
    def __init__(self, quiet: bool = False, explain: bool = False):
        self.quiet = quiet
        self.explain = explain
        self.counts = {"built": 0, "cached": 0, "failed": 0}
        self._progress = None
        self._task = None

    def __enter__(self):
        if not self.quiet and sys.stderr.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TimeElapsedColumn(), transient=True)
            self._progress.__enter__()
            self._task = self._progress.add_task("building", total=None)
        return self

    def __exit__(self, *exc):
        if self._progress is not None:
            self._progress.__exit__(*exc)
            self._progress = None

    def _echo(self, text: str, err: bool = False):
        if self._progress is not None:
            self._progress.console.print(text, markup=False, highlight=False)
        else:
            click.echo(text, err=err)

    def on_result(self, r, n: int, total: int) -> None:
        self.counts[r.status] = self.counts.get(r.status, 0) + 1
        if self._progress is not None:
            c = self.counts
            self._progress.update(self._task, total=total, completed=n,
                                  description=f"built {c['built']} cached {c['cached']} failed {c['failed']}")
        if r.status == "failed":
            self._echo(f"FAILED  {r.error}", err=True)
        elif not self.quiet and (r.status == "built" or self.explain):
            extra = f"  ({len(r.warnings)} warning{'s' if len(r.warnings) != 1 else ''})" if r.warnings else ""
            self._echo(f"[{n}/{total}] {r.status:6s} {r.id}  {r.seconds:.2f}s{extra}")
        if self.explain and r.status != "failed":
            for s in r.steps:
                if s.get("ran"):
                    self._echo(f"    {s['step']}: {s['reason']}")
            if not any(s.get("ran") for s in r.steps):
                self._echo(f"    {r.reason}")

    def summary(self, report, out_dir) -> None:
        counts = report.counts()
        text = ", ".join(f"{counts[k]} {k}" for k in ("built", "cached", "failed") if counts.get(k)) or "nothing to build"
        if report.removed:
            text += f", {len(report.removed)} stale output(s) removed"
        if report.cache_dropped:
            text += f", {len(report.cache_dropped)} corrupt cache entr{'y' if len(report.cache_dropped) == 1 else 'ies'} rebuilt"
        click.echo(f"assetpipe: {text} in {report.seconds:.2f}s -> {out_dir}")
