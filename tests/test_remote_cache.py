"""The remote cache tier (assetpipe.cache.remote) against a real S3-compatible server (moto's
server, its own process on 127.0.0.1) and a shared folder (file://): a second machine gets
every step from it, a corrupt remote blob or record is detected, reported and rebuilt, two
clients building the same inputs at once both succeed, an unreachable store is said once."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from farm_fixtures import free_port, make_model, tree

from assetpipe.build import run_build
from assetpipe.cache.remote import TieredStore, open_store
from assetpipe.cache.store import Store
from assetpipe.core.hashing import digest_bytes
from assetpipe.options import DEFAULT_BUILD_OPTIONS

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def s3(s3_server):
    return s3_server  # tests/conftest.py: one moto server for the session


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("models")
    make_model(src, "small", 12, seed=1, texture=32)
    make_model(src, "wavy", 20, seed=2, texture=16)
    return src


def _build(models, out, local, cache):
    """A build as a fresh machine: its own output folder and local cache tier."""
    store = TieredStore(Store(local), cache) if isinstance(cache, str) else Store(local)
    return run_build([models], out, DEFAULT_BUILD_OPTIONS, cache_dir=store), store


def _steps(report) -> list[tuple[str, bool]]:
    return [(s["step"], s["ran"]) for r in report.results for s in r.steps]


def _digest_of(key: str) -> str:
    return "xxh3:" + "".join(key.split("/")[-2:])


@pytest.fixture(scope="module")
def seeded(s3, models, tmp_path_factory):
    """A first machine's build through the remote cache: (url, its output tree, its steps)."""
    tmp = tmp_path_factory.mktemp("seed")
    url = s3.url("shared")
    report, store = _build(models, tmp / "out", tmp / "local", url)
    assert not report.failed and store.notice is None
    assert _steps(report) and all(ran for _, ran in _steps(report)), _steps(report)
    return url, tree(tmp / "out"), _steps(report)


def test_remote_holds_whole_blobs_named_by_content(s3, seeded):
    keys = s3.keys("shared/")
    assert any(k.startswith("shared/actions/") for k in keys)
    blobs = [k for k in keys if k.startswith("shared/objects/")]
    assert blobs and all(digest_bytes(s3.get(k)) == _digest_of(k) for k in blobs)


def test_second_machine_gets_every_step_from_the_remote_cache(seeded, models, tmp_path):
    url, ref, first_steps = seeded
    report, store = _build(models, tmp_path / "out", tmp_path / "local", url)
    assert not report.failed
    assert [s for s, ran in _steps(report) if ran] == [] and len(_steps(report)) == len(first_steps)
    assert [r.status for r in report.results] == ["cached"] * 2
    assert tree(tmp_path / "out") == ref
    assert store.moved["records_fetched"] == len(first_steps)  # one record per step (no step is shared here)
    assert store.moved["up"] == 0  # nothing rebuilt, nothing uploaded


def test_corrupt_remote_blob_is_reported_and_rebuilt(s3, seeded, models, tmp_path):
    url, ref, _ = seeded
    blobs = sorted(s3.keys("shared/objects/"), key=lambda k: len(s3.get(k)))
    victim = blobs[-1]  # the largest: truncated, as by an interrupted copy with some other tool
    good = s3.get(victim)
    s3.put(victim, good[: len(good) // 2])
    report, _ = _build(models, tmp_path / "out", tmp_path / "local", url)
    assert not report.failed
    reported = [d for d in report.cache_dropped if d.startswith("remote ") and _digest_of(victim) in d]
    assert len(reported) == 1 and "does not match its digest" in reported[0], report.cache_dropped
    assert any(ran for _, ran in _steps(report))  # the step that made it ran again
    assert tree(tmp_path / "out") == ref
    assert s3.get(victim) == good  # uploaded again, whole


def test_corrupt_remote_record_is_rebuilt(s3, seeded, models, tmp_path):
    url, ref, _ = seeded
    victim = sorted(s3.keys("shared/actions/"))[0]
    good = s3.get(victim)
    s3.put(victim, good[:-7])
    report, _ = _build(models, tmp_path / "out", tmp_path / "local", url)
    assert not report.failed
    assert [d for d in report.cache_dropped if d.startswith("remote ") and "record is corrupt" in d]
    assert [ran for _, ran in _steps(report)].count(True) == 1
    assert tree(tmp_path / "out") == ref
    assert s3.get(victim) == good


def test_two_clients_building_the_same_inputs_at_once(s3, seeded, models, tmp_path):
    """Two machines (processes with their own local tier and output folder), one cold prefix."""
    url = s3.url("race")
    procs = []
    for k in (1, 2):
        env = {**os.environ, "PYTHONPATH": str(REPO), "ASSETPIPE_CACHE": str(tmp_path / f"local{k}")}
        procs.append(subprocess.Popen([sys.executable, "-m", "assetpipe.cli", "build", str(models), "-q",
                                       "-o", str(tmp_path / f"out{k}"), "--cache", url], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        assert "remote cache" not in out + err
    assert tree(tmp_path / "out1") == tree(tmp_path / "out2") == seeded[1]
    blobs = [k for k in s3.keys("race/") if "/objects/" in k]
    assert blobs and all(digest_bytes(s3.get(k)) == _digest_of(k) for k in blobs)
    # a third machine finds every step
    report, _ = _build(models, tmp_path / "out3", tmp_path / "local3", url)
    assert not any(ran for _, ran in _steps(report))


def test_shared_folder_url(seeded, models, tmp_path):
    """file:// (a shared filesystem): written aside and moved into place; hits as with S3."""
    url = (tmp_path / "shared").as_uri()
    first, _ = _build(models, tmp_path / "out1", tmp_path / "local1", url)
    second, _ = _build(models, tmp_path / "out2", tmp_path / "local2", url)
    assert [r for _, r in _steps(second)] == [False] * len(_steps(first))
    assert tree(tmp_path / "out2") == tree(tmp_path / "out1") == seeded[1]
    assert list((tmp_path / "shared" / "tmp").iterdir()) == []  # nothing left aside


def _free_port_with_404() -> int:
    """A free port whose number holds "404" (an unreachable endpoint's error message then does)."""
    import socket

    for port in (*range(40400, 40500), *range(14040, 14050), *range(24040, 24050)):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError("no free port with 404 in its number")


@pytest.mark.parametrize("port_kind", ["any", "with-404"])
def test_unreachable_remote_builds_locally_and_says_so_once(seeded, models, tmp_path, monkeypatch, caplog,
                                                            port_kind):
    # nothing listens there; the second case once passed for an empty store (the "404" in the URL
    # of the connection error read as "not found")
    port = free_port() if port_kind == "any" else _free_port_with_404()
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
    with caplog.at_level(logging.WARNING, logger="assetpipe.cache"):
        report, store = _build(models, tmp_path / "out", tmp_path / "local", "s3://nowhere/cache")
    assert not report.failed and all(ran for _, ran in _steps(report))
    said = [r.getMessage() for r in caplog.records if r.name == "assetpipe.cache"]
    assert len(said) == 1 and "s3://nowhere/cache unreachable" in said[0] and "local cache only" in said[0], said
    assert store.notice in said[0]
    assert tree(tmp_path / "out") == seeded[1]


def test_open_store_chooses_the_tier(tmp_path):
    assert type(open_store(tmp_path / "c")) is Store
    tiered = open_store("s3://bucket/prefix", local=tmp_path / "l")
    assert isinstance(tiered, TieredStore) and tiered.root == tmp_path / "l"


def test_not_found_is_read_from_the_error_structure_not_its_text():
    from botocore.exceptions import ClientError, EndpointConnectionError

    from assetpipe.cache.remote import _is_not_found

    assert _is_not_found(ClientError({"Error": {"Code": "NoSuchKey"}}, "GetObject"))
    assert _is_not_found(ClientError({"Error": {"Code": "404"}, "ResponseMetadata": {"HTTPStatusCode": 404}},
                                     "HeadObject"))
    assert _is_not_found(FileNotFoundError("s3://b/k"))
    assert not _is_not_found(EndpointConnectionError(endpoint_url="http://127.0.0.1:40412/b/k"))
    assert not _is_not_found(ClientError({"Error": {"Code": "AccessDenied"},
                                          "ResponseMetadata": {"HTTPStatusCode": 403}}, "GetObject"))
    assert not _is_not_found(OSError("Not Found in http://host:4040"))
