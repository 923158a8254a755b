"""``assetpipe cache stats`` / ``gc``: build, change options, rebuild, collect; the current outputs
still build as a no-op and restore from the cache; the old options' entries are gone."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from assetpipe.cache.maintenance import collect, parse_age, parse_size, stats
from assetpipe.cache.store import Store
from assetpipe.cli import main

REPO = Path(__file__).resolve().parents[1]


def cli(*args: str):
    r = CliRunner().invoke(main, list(args), catch_exceptions=False)
    return r


def age_everything(cache: Path, seconds: float) -> None:
    """As if ``seconds`` passed since every cache entry was last used."""
    t = time.time() - seconds
    for p in [*(cache / "objects").rglob("*"), *(cache / "actions").rglob("*")]:
        if p.is_file():
            os.utime(p, (t, t))


@pytest.fixture
def project(tmp_path):
    shutil.copytree(REPO / "examples", tmp_path / "src", ignore=shutil.ignore_patterns("*.py"))
    return tmp_path


def build(project: Path, *flags: str) -> dict:
    rep = project / "report.json"
    r = cli("build", str(project / "src"), "-o", str(project / "out"), "--cache", str(project / "cache"),
            "-j", "1", "--json", str(rep), *flags)
    assert r.exit_code == 0, r.output
    return {a["id"]: a for a in json.loads(rep.read_text())["assets"]}


def test_collect_keeps_what_the_current_outputs_need(project):
    cache = project / "cache"
    build(project)  # options A
    build(project, "--no-lod", "--max-texture-size", "8")  # options B: new lod-less encodes, smaller textures
    before = stats(cache)
    assert before.records > 0 and before.last_build["lookups"] > 0
    age_everything(cache, 3600)
    r = cli("cache", "gc", "--max-size", "1", "--cache", str(cache))
    assert r.exit_code == 0 and r.output.startswith("removed "), r.output
    after = stats(cache)
    assert 0 < after.size < before.size and after.records < before.records
    # the current outputs: a no-op
    again = build(project, "--no-lod", "--max-texture-size", "8")
    assert {a["status"] for a in again.values()} == {"cached"}
    assert {a["reason"] for a in again.values()} == {"up to date"}
    # an output deleted by hand is restored from the cache, no step rerun
    (project / "out" / "crate.vtx").unlink()
    restored = build(project, "--no-lod", "--max-texture-size", "8")
    assert restored["crate"]["status"] == "cached" and "restored: crate.vtx" in restored["crate"]["reason"], (restored["crate"]["reason"], restored["crate"]["steps"])
    assert all(not s["ran"] for s in restored["crate"]["steps"])
    # options A's entries were collected: building with them again reruns their steps (without the
    # collection every one of them would be a cache hit), while the steps both share still hit
    old = build(project)
    ran = {s["step"] for s in old["crate"]["steps"] if s["ran"]}
    assert {"lod", "encode", "texture crate.png (baseColor)"} <= ran and "import" not in ran, old["crate"]["steps"]


def test_stats_reports_the_hit_rate_of_the_last_build(project):
    cache = project / "cache"
    build(project)
    build(project, "--no-lod")  # import, mesh and texture steps hit; lod-less encodes miss
    r = cli("cache", "stats", "--cache", str(cache), "--json")
    s = json.loads(r.output)
    lb = s["lastBuild"]
    assert 0 < lb["hits"] < lb["lookups"]
    assert s["records"] > 0 and s["blobs"] > 0 and s["size"] > 0 and s["outputFolders"] == 1
    text = cli("cache", "stats", "--cache", str(cache)).output
    assert f"{lb['hits']} of {lb['lookups']} step lookups hit" in text


def test_older_than_removes_only_old_unneeded_entries(project):
    cache = project / "cache"
    build(project)
    build(project, "--no-lod")
    age_everything(cache, 3 * 86400)
    r = cli("cache", "gc", "--older-than", "2d", "--cache", str(cache))
    assert r.exit_code == 0 and "removed 0 step" not in r.output, r.output
    assert {a["status"] for a in build(project, "--no-lod").values()} == {"cached"}


def test_entries_used_by_a_running_build_are_kept(project):
    cache = project / "cache"
    build(project)
    build(project, "--no-lod")
    age_everything(cache, 3600)
    from assetpipe.cache.maintenance import _protected

    _, needed = _protected(cache)
    record = next(p for p in (cache / "actions").rglob("*") if p.is_file() and p.parent.name + p.name not in needed)
    store = Store(cache)
    session = store.begin_build()
    now = time.time()
    os.utime(session[1], (now - 1200, now - 1200))  # a build that started 20 minutes ago and still runs ...
    os.utime(record, (now - 900, now - 900))  # ... used this record 15 minutes ago (older than the grace period)
    try:
        collect(cache, max_size=1)
        assert record.exists()
    finally:
        store.end_build(session)
    collect(cache, max_size=1)
    assert not record.exists()  # once that build ended, the record can go


def test_no_op_builds_do_not_walk_or_collect(project, monkeypatch):
    build(project)
    import assetpipe.cache.maintenance as m

    monkeypatch.setattr(m, "auto_collect", lambda root: pytest.fail("a no-op build collected"))
    assert {a["status"] for a in build(project).values()} == {"cached"}


def test_automatic_limit_collects_after_a_build(project, monkeypatch):
    build(project)
    age_everything(project / "cache", 3600)
    monkeypatch.setenv("ASSETPIPE_CACHE_MAX_SIZE", "1K")
    size_before = stats(project / "cache").size
    build(project, "--no-lod")  # writes to the cache, which is then far above 1 KiB
    assert stats(project / "cache").size < size_before
    assert {a["status"] for a in build(project, "--no-lod").values()} == {"cached"}


@pytest.mark.parametrize("text, n", [("1024", 1024), ("2K", 2048), ("1.5G", int(1.5 * 1024 ** 3)), ("10GiB", 10 * 1024 ** 3),
                                     ("500mb", 500 * 1024 ** 2)])
def test_parse_size(text, n):
    assert parse_size(text) == n


def test_bad_sizes_and_ages_are_refused(project):
    with pytest.raises(ValueError, match="not a size: '12 apples'"):
        parse_size("12 apples")
    with pytest.raises(ValueError, match="not an age: '3 fortnights'"):
        parse_age("3 fortnights")
    assert parse_age("2w") == 14 * 86400
    r = CliRunner().invoke(main, ["cache", "gc", "--cache", str(project / "c")])
    assert r.exit_code == 2 and "give --max-size SIZE and/or --older-than AGE" in r.output
