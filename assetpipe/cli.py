"""The ``assetpipe`` command line. Defaults come from the options dataclasses."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from assetpipe import __version__
from assetpipe.core.errors import AssetpipeError
from assetpipe.options import DEFAULT_BUILD_OPTIONS
from assetpipe.pipelines.lod_options import SIMPLIFIERS
from assetpipe.pipelines.texture_options import TEXTURE_CODECS

_D = DEFAULT_BUILD_OPTIONS


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="assetpipe")
def main() -> None:
    """Content-hashed asset pipeline: glTF 2.0 / OBJ to engine-ready idx/vtx/json."""


def _build_options(layout: str, lod_ratios: str | None, no_lod: bool, simplifier: str | None,
                   lock_border: bool, max_texture_size: int | None, texture_compression: str | None = None,
                   texture_zstd: bool = False):
    """BuildOptions from the command line; unspecified values keep the dataclass defaults."""
    import dataclasses

    from assetpipe.options import BuildOptions

    d = DEFAULT_BUILD_OPTIONS
    try:
        mesh = dataclasses.replace(d.mesh, layout=tuple(a.strip() for a in layout.split(",")))
        lod = None
        if not no_lod:
            changes = {}
            if lod_ratios:
                changes["ratios"] = tuple(float(eval_ratio(r)) for r in lod_ratios.split(","))
            if simplifier:
                changes["simplifier"] = simplifier
            if lock_border:
                changes["lock_border"] = True
            lod = dataclasses.replace(d.lod, **changes)
        texture = dataclasses.replace(d.texture, max_size=max_texture_size) if max_texture_size else d.texture
        if texture_compression:
            texture = dataclasses.replace(texture, compression=texture_compression)
        if texture_zstd:
            texture = dataclasses.replace(texture, supercompression="zstd")
    except (ValueError, TypeError) as exc:
        raise click.BadParameter(str(exc)) from None
    return BuildOptions(mesh=mesh, lod=lod, texture=texture)


def eval_ratio(text: str) -> float:
    """'0.25' or '1/4' -> 0.25 (no eval)."""
    num, _, den = text.strip().partition("/")
    return float(num) / float(den) if den else float(num)


@main.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", type=click.Path(path_type=Path), default=Path("out"),
              show_default=True, help="Output folder.")
@click.option("--json", "json_report", type=click.Path(path_type=Path), default=None,
              help="Write a JSON report (one entry per input) to this file.")
@click.option("-j", "--jobs", type=click.IntRange(1, 256), default=1, show_default=True,
              help="Worker processes for the build steps (outputs are identical for any value).")
@click.option("--cache", "cache_dir", type=click.Path(path_type=Path), default=None,
              help="Cache folder [default: $ASSETPIPE_CACHE, else $XDG_CACHE_HOME/assetpipe, else ~/.cache/assetpipe].")
@click.option("--explain", is_flag=True, help="Say, for every step that ran, why it ran.")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures and the summary line.")
@click.option("--layout", default=",".join(_D.mesh.layout), show_default=True,
              help="Vertex attributes, comma-separated: position first, then any of uv0, normal, tangent, uv1, color.")
@click.option("--lod-ratios", default=None, help=f"LOD triangle ratios, e.g. '1,1/2,1/4' [default: {','.join(f'{r:g}' for r in _D.lod.ratios)}].")
@click.option("--no-lod", is_flag=True, help="Build LOD0 only.")
@click.option("--simplifier", type=click.Choice(SIMPLIFIERS), default=None,
              help=f"LOD simplifier [default: {_D.lod.simplifier}].")
@click.option("--lock-border", is_flag=True, help="Keep open mesh borders in place in every LOD.")
@click.option("--max-texture-size", type=click.IntRange(1, 16384), default=None,
              help="Downsize textures so neither side exceeds this (power of two steps).")
@click.option("--texture-compression", type=click.Choice(TEXTURE_CODECS), default=None,
              help=f"GPU block compression of the KTX2 textures: bc (BC7/BC5/BC4), etc2 (ETC2/EAC) "
                   f"[default: {_D.texture.compression}].")
@click.option("--texture-zstd", is_flag=True, help="Zstandard-supercompress the KTX2 levels (KTX2 scheme 2).")
def build(inputs, out_dir, json_report, jobs, cache_dir, explain, quiet, layout, lod_ratios, no_lod,
          simplifier, lock_border, max_texture_size, texture_compression, texture_zstd) -> None:
    """Build INPUTS (.gltf, .glb, .obj files, or folders searched recursively) into OUT."""
    from assetpipe.build import run_build
    from assetpipe.progress import Reporter

    options = _build_options(layout, lod_ratios, no_lod, simplifier, lock_border, max_texture_size,
                             texture_compression, texture_zstd)
    reporter = Reporter(quiet=quiet, explain=explain)
    try:
        with reporter:
            report = run_build(list(inputs), out_dir, options, jobs=jobs, cache_dir=cache_dir,
                               on_result=reporter.on_result)
    except AssetpipeError as exc:
        raise click.ClickException(str(exc)) from None
    if json_report:
        report.write_json(json_report)
    reporter.summary(report, out_dir)
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


def _register_renderer_commands() -> None:
    from assetpipe.renderer.cli_commands import preview, validate  # light: vulkan is imported when they run

    main.add_command(validate)
    main.add_command(preview)


_register_renderer_commands()

if __name__ == "__main__":  # pragma: no cover
    main()
