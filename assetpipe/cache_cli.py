"""``assetpipe cache stats`` and ``assetpipe cache gc`` (the logic is in assetpipe.cache.maintenance)."""

from __future__ import annotations

import json
from pathlib import Path

import click

_CACHE_HELP = "Cache folder [default: $ASSETPIPE_CACHE, else $XDG_CACHE_HOME/assetpipe, else ~/.cache/assetpipe]."


def _root(cache_dir: Path | None) -> Path:
    from assetpipe.cache.store import default_cache_dir

    return Path(cache_dir) if cache_dir else default_cache_dir()


@click.group("cache")
def cache() -> None:
    """Inspect and collect the build cache."""


@cache.command("stats")
@click.option("--cache", "cache_dir", type=click.Path(path_type=Path), default=None, help=_CACHE_HELP)
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
def stats_cmd(cache_dir: Path | None, as_json: bool) -> None:
    """Size, entries, output folders, and the hit rate of the last build."""
    from assetpipe.cache.maintenance import stats

    s = stats(_root(cache_dir))
    click.echo(json.dumps(s.to_json(), indent=2) if as_json else "\n".join(s.lines()))


@cache.command("gc")
@click.option("--cache", "cache_dir", type=click.Path(path_type=Path), default=None, help=_CACHE_HELP)
@click.option("--max-size", default=None, help="Shrink the cache to at most this size (e.g. 500M, 2G), least recently used first.")
@click.option("--older-than", default=None, help="Remove what no build used for this long (e.g. 30d, 12h).")
@click.option("--dry-run", is_flag=True, help="Say what would be removed; remove nothing.")
def gc_cmd(cache_dir: Path | None, max_size: str | None, older_than: str | None, dry_run: bool) -> None:
    """Remove least recently used cache entries; never what current outputs or running builds need."""
    from assetpipe.cache.maintenance import collect, parse_age, parse_size

    if max_size is None and older_than is None:
        raise click.UsageError("give --max-size SIZE and/or --older-than AGE")
    try:
        size = parse_size(max_size) if max_size is not None else None
        age = parse_age(older_than) if older_than is not None else None
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    result = collect(_root(cache_dir), max_size=size, older_than_s=age, dry_run=dry_run)
    click.echo(("would have " if dry_run else "") + result.line())
