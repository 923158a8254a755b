"""The ``assetpipe`` command line. Defaults come from the options dataclasses."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from assetpipe import __version__
from assetpipe.errors import AssetpipeError


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="assetpipe")
def main() -> None:
    """Content-hashed asset pipeline: glTF 2.0 / OBJ to engine-ready idx/vtx/json."""


@main.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path), default=Path("out"),
              show_default=True, help="Output folder.")
@click.option("--json", "json_report", type=click.Path(path_type=Path), default=None,
              help="Write a JSON report (one entry per input) to this file.")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures and the summary line.")
def build(inputs: tuple[Path, ...], out_dir: Path, json_report: Path | None, quiet: bool) -> None:
    """Build INPUTS (.gltf, .glb, .obj files, or folders searched recursively) into OUT."""
    from assetpipe.build import run_build
    from assetpipe.model_build import DEFAULT_BUILD_OPTIONS

    def on_result(r, n, total):
        if r.status == "failed":
            click.echo(f"FAILED  {r.error}", err=True)
        elif not quiet:
            extra = f"  ({len(r.warnings)} warning{'s' if len(r.warnings) != 1 else ''})" if r.warnings else ""
            click.echo(f"[{n}/{total}] {r.status:6s} {r.id}  {r.seconds:.2f}s{extra}")

    try:
        report = run_build(list(inputs), out_dir, DEFAULT_BUILD_OPTIONS, on_result=on_result)
    except AssetpipeError as exc:
        raise click.ClickException(str(exc)) from None
    if json_report:
        report.write_json(json_report)
    counts = report.to_json()["counts"]
    summary = ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "nothing to build"
    click.echo(f"assetpipe: {summary} in {report.seconds:.2f}s -> {out_dir}")
    if report.failed:
        sys.exit(1)


@main.command()
@click.argument("model_json", type=click.Path(exists=True, dir_okay=False, path_type=Path))
def inspect(model_json: Path) -> None:
    """Summarise a built model (ID.json) and check its files for consistency."""
    from assetpipe.inspect import check_model, summarize

    problems = check_model(model_json)
    click.echo(summarize(model_json))
    if problems:
        for p in problems:
            click.echo(f"PROBLEM {p}", err=True)
        sys.exit(1)
    click.echo("consistent: yes")


if __name__ == "__main__":  # pragma: no cover
    main()
