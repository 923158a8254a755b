"""Click commands ``validate`` and ``preview`` for the main ``assetpipe`` group.

Register them with::

    from assetpipe.renderer.cli_commands import preview, validate
    main.add_command(validate)
    main.add_command(preview)
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from assetpipe.core.cli_types import FiniteFloatRange
from assetpipe.core.errors import AssetpipeError

from .results import MAX_RENDER_SIZE, MIN_VALIDATE_SIZE


def find_built_models(paths: tuple[str, ...] | list[str]) -> list[Path]:
    """``ID.json`` files from the arguments: files as given, directories searched for sidecars."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found += sorted(s.with_name(s.name[: -len(".asset.json")] + ".json") for s in p.rglob("*.asset.json"))
        else:
            found.append(p)
    return found


def _list_checks(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    if not value or ctx.resilient_parsing:
        return
    from .checks import REGISTRY  # noqa: PLC0415

    for c in REGISTRY:
        click.echo(f"{c.name}\n  measures:  {c.measures}\n  tolerance: {c.tolerance}\n  why:       {c.reason}\n")
    ctx.exit(0)


@click.command("validate")
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option("--list-checks", is_flag=True, expose_value=False, is_eager=True, callback=_list_checks,
              help="Print every check: what it measures, its tolerance and why, then exit.")
@click.option("--sources", "source_root", type=click.Path(file_okay=False),
              help="Directory holding the source models (searched recursively) for the source check.")
@click.option("--size", default=256, show_default=True, type=click.IntRange(MIN_VALIDATE_SIZE, MAX_RENDER_SIZE),
              help="Render size in pixels (square).")
@click.option("--checks", default="all", show_default=True,
              help="Comma-separated checks to run (load, vulkan, bounds, silhouette, source, lods, textures, roles).")
@click.option("--no-validation-layer", is_flag=True, help="Do not enable the Khronos validation layer.")
@click.option("--timeout", default=120.0, show_default=True, type=FiniteFloatRange(min=0, min_open=True),
              help="Seconds allowed per asset.")
@click.option("--json", "json_report", type=click.Path(dir_okay=False), help="Write a JSON report here.")
@click.option("--json-report", "json_report", type=click.Path(dir_okay=False), hidden=True)
@click.option("--junit", type=click.Path(dir_okay=False), help="Write a JUnit XML report here.")
@click.option("--baseline", type=click.Path(exists=True, dir_okay=False),
              help="Accept the known differences this baseline file lists (per model and check).")
@click.option("--write-baseline", type=click.Path(dir_okay=False),
              help="Write a baseline accepting every failure of this run.")
@click.option("-j", "--jobs", default=1, show_default=True, type=click.IntRange(1, 64),
              help="Renderer processes validating models in parallel.")
@click.option("--in-process", is_flag=True, help="Render in this process (no crash isolation).")
@click.option("-v", "--verbose", is_flag=True, help="Print the figures of every check.")
def validate(paths: tuple[str, ...], source_root: str | None, size: int, checks: str, no_validation_layer: bool,
             timeout: float, json_report: str | None, junit: str | None, baseline: str | None,
             write_baseline: str | None, jobs: int, in_process: bool, verbose: bool) -> None:
    """Validate built models (OUT/ID.json files or OUT directories) by rendering them headless."""
    from . import baseline as baselines  # noqa: PLC0415
    from .batch import validate_batch  # noqa: PLC0415
    from .reports import measured_over, summary, write_json_report, write_junit_report  # noqa: PLC0415
    from .validate import CHECKS, ValidateOptions  # noqa: PLC0415

    selected = tuple(c.strip() for c in checks.split(",") if c.strip() and c.strip() != "all")
    unknown = set(selected) - set(CHECKS)
    if unknown:
        raise click.BadParameter(f"unknown checks {sorted(unknown)} (choose from {', '.join(CHECKS)})")
    models = find_built_models(paths)
    if not models:
        raise click.UsageError("no built models found")
    opts = ValidateOptions(width=size, height=size, checks=selected, validation_layer=not no_validation_layer,
                           timeout_s=timeout, source_root=source_root)

    def show(r) -> None:  # type: ignore[no-untyped-def]
        status = "ok    " if r.passed else "FAIL  "
        t = sum(r.timings.values())
        click.echo(f"{status}{r.model}  ({t:.2f} s)")
        if r.error:
            click.echo(f"      {r.error}")
        for c in r.checks:
            if c.status == "fail":
                over = "; ".join(f"{q} {v:g} > {t:g}" for q, v, t in measured_over(c))
                click.echo(f"      {c.name} [{over}]: {'; '.join(c.messages) or 'failed'}")
            elif c.accepted:
                click.echo(f"      {c.name}: {c.accepted}")
        for c in r.checks:
            if c.status == "skip":
                click.echo(f"      skipped {c.name}: {'; '.join(c.messages)}")
            if verbose:
                click.echo(f"      {c.name}: {c.status} {c.figures}")

    try:
        accepted = baselines.load_baseline(baseline) if baseline else None
        results = validate_batch(models, opts, isolate=not in_process, progress=show, jobs=jobs, baseline=accepted)
    except AssetpipeError as exc:
        click.echo(f"assetpipe: {exc}", err=True)
        sys.exit(2)
    if write_baseline:
        baselines.write_baseline(results, write_baseline)
    if json_report:
        write_json_report(results, json_report)
    if junit:
        write_junit_report(results, junit)
    s = summary(results)
    click.echo(f"{s['passed']} of {s['models']} models passed")
    sys.exit(0 if s["failed"] == 0 else 1)


@click.command("preview")
@click.argument("model_json", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="PNG to write (default: ID-preview.png).")
@click.option("--size", default=256, show_default=True, type=click.IntRange(1, MAX_RENDER_SIZE),
              help="Size of each view in pixels.")
def preview(model_json: str, output: str | None, size: int) -> None:
    """Write a contact sheet of a built model: views, LODs, texture mips."""
    from .preview import make_preview  # noqa: PLC0415

    src = Path(model_json)
    out = Path(output) if output else src.with_name(src.name[: -len(".json")] + "-preview.png")
    try:
        click.echo(make_preview(src, out, view_px=size))
    except AssetpipeError as exc:
        click.echo(f"assetpipe: {exc}", err=True)
        sys.exit(2)
