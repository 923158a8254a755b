"""The content-addressed store: verified blobs and records, unusable folders, the default location."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from assetpipe.core.errors import CacheError
from assetpipe.core.hashing import digest_bytes
from assetpipe.cache import store as store_mod
from assetpipe.cache.store import Store, default_cache_dir


@pytest.fixture
def store(tmp_path) -> Store:
    return Store(tmp_path / "cache")


def test_layout_is_created(tmp_path):
    s = Store(tmp_path / "a" / "b")
    assert sorted(p.name for p in s.root.iterdir()) == ["actions", "objects", "tmp"]


def test_blob_round_trip(store):
    data = os.urandom(5000)
    d = store.put_blob(data)
    assert d == digest_bytes(data)
    hexpart = d.split(":", 1)[1]
    assert store.blob_path(d) == store.root / "objects" / hexpart[:2] / hexpart[2:]
    assert store.blob_path(d).read_bytes() == data
    assert store.get_blob(d) == data and store.has_blob(d)
    assert store.put_blob(data) == d  # idempotent
    assert store.put_blob(b"") == digest_bytes(b"") and store.get_blob(digest_bytes(b"")) == b""
    assert list((store.root / "tmp").iterdir()) == []
    assert store.dropped == []


def test_blob_put_in_pieces_is_the_blob_of_their_concatenation(store):
    pieces = [b"head", memoryview(os.urandom(3 << 20)), b"", memoryview(bytearray(b"tail"))]
    whole = b"".join(pieces)
    d = store.put_blob(pieces)
    assert d == digest_bytes(whole)
    assert store.blob_path(d).read_bytes() == whole and store.get_blob(d) == whole
    assert store.put_blob(whole) == d and store.put_blob(tuple(pieces)) == d


def test_absent_blob(store):
    d = digest_bytes(b"never stored")
    assert store.get_blob(d) is None and not store.has_blob(d)
    assert store.dropped == []


def test_corrupt_blob_is_dropped_and_reported(store):
    d = store.put_blob(b"good content")
    store.blob_path(d).write_bytes(b"bad content!")
    assert store.get_blob(d) is None
    assert not store.blob_path(d).exists()
    assert len(store.dropped) == 1
    assert d.split(":")[1][2:] in store.dropped[0] and "does not match its digest" in store.dropped[0]


def test_put_blob_rewrites_a_corrupt_existing_blob(store):
    d = store.put_blob(b"payload")
    store.blob_path(d).write_bytes(b"truncat")
    assert store.put_blob(b"payload") == d
    assert store.blob_path(d).read_bytes() == b"payload"
    assert store.get_blob(d) == b"payload"
    assert len(store.dropped) == 1


def test_record_round_trip_with_checksum(store):
    a, b = store.put_blob(b"a"), store.put_blob(b"b")
    key = digest_bytes(b"some key")
    rec = {"blobs": {"x": a, "y": b}, "meta": {"n": 1, "f": 0.1, "s": "\u00e9"}}
    store.put_record(key, rec)
    assert store.get_record(key) == rec
    raw = json.loads((store.root / "actions" / key[5:7] / key[7:]).read_bytes())
    assert set(raw) == {"check", "record"} and raw["check"].startswith("xxh3:")
    assert store.get_record(digest_bytes(b"other key")) is None
    assert store.dropped == []


@pytest.mark.parametrize("damage", [
    lambda raw: raw.replace(b'"n":1', b'"n":2'),  # content changed: checksum fails
    lambda raw: raw[: len(raw) // 2],  # truncated
    lambda raw: b"",
    lambda raw: b"[1, 2]",
    lambda raw: b'{"record": {}}',  # no checksum
    lambda raw: b"\xff\xfe garbage",
    lambda raw: b'{"check": "%s", "record": [1]}' % digest_bytes(b"[1]").encode(),  # checksum fine, not a record
])
def test_corrupt_record_is_dropped(store, damage):
    key = digest_bytes(b"k")
    store.put_record(key, {"blobs": {}, "meta": {"n": 1}})
    path = store.root / "actions" / key[5:7] / key[7:]
    path.write_bytes(damage(path.read_bytes()))
    assert store.get_record(key) is None
    assert not path.exists()
    assert len(store.dropped) == 1 and "record is corrupt" in store.dropped[0]


def test_record_naming_a_missing_blob_is_dropped(store):
    key = digest_bytes(b"k")
    ghost = digest_bytes(b"never stored")
    store.put_record(key, {"blobs": {"x": store.put_blob(b"ok"), "y": ghost}})
    assert store.get_record(key) is None
    assert store.get_record(key) is None  # and stays gone
    assert len(store.dropped) == 1 and ghost in store.dropped[0]


def test_record_naming_a_corrupt_blob_is_dropped_with_the_blob(store):
    key = digest_bytes(b"k")
    d = store.put_blob(b"blob")
    store.put_record(key, {"blobs": {"x": d}})
    store.blob_path(d).write_bytes(b"blub")
    assert store.get_record(key) is None
    assert not store.blob_path(d).exists()
    assert len(store.dropped) == 2  # the blob, then the record


def test_cache_root_that_is_a_file_is_a_cache_error(tmp_path):
    f = tmp_path / "file"
    f.write_bytes(b"")
    with pytest.raises(CacheError, match=r"cannot use the cache folder .*file"):
        Store(f)
    with pytest.raises(CacheError, match="Not a directory"):
        Store(f / "below")


def test_write_failure_is_a_cache_error(store, monkeypatch):
    def full(*a, **k):
        raise OSError(28, "No space left on device")

    import tempfile  # the store imports it when it first writes a blob

    monkeypatch.setattr(tempfile, "mkstemp", full)
    with pytest.raises(CacheError, match="cannot write to the cache folder .*No space left on device"):
        store.put_blob(b"data")


def test_failing_rename_leaves_no_temporary(store, monkeypatch):
    def fail(src, dst):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(store_mod.os, "replace", fail)
    with pytest.raises(CacheError, match="Input/output error"):
        store.put_blob(b"data")
    assert list((store.root / "tmp").iterdir()) == []


def test_cache_made_unusable_after_opening_is_a_cache_error(store):
    # the objects folder replaced by a file (a full or broken disk behaves alike): the shard
    # folder cannot be created; the user must get a CacheError, not an internal error
    import shutil
    shutil.rmtree(store.root / "objects")
    (store.root / "objects").write_bytes(b"")
    with pytest.raises(CacheError, match="cache folder .*Not a directory"):
        store.put_blob(b"data")
    with pytest.raises(CacheError, match="cache folder .*Not a directory"):
        store.get_blob(digest_bytes(b"data"))


def test_shard_folder_that_cannot_be_created_is_a_cache_error(store, monkeypatch):
    def denied(self, *a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(store_mod.Path, "mkdir", denied)
    with pytest.raises(CacheError, match="cannot write to the cache folder .*Permission denied"):
        store.put_blob(b"data")
    with pytest.raises(CacheError, match="cannot write to the cache folder .*Permission denied"):
        store.put_record(digest_bytes(b"k"), {"blobs": {}})


def test_bad_digest_refused(store):
    with pytest.raises(ValueError, match="not a digest: .xxh3:not-hex!."):
        store.get_blob("xxh3:not-hex!")


def test_default_cache_dir_env_precedence(monkeypatch, tmp_path):
    monkeypatch.setenv("ASSETPIPE_CACHE", str(tmp_path / "explicit"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert default_cache_dir() == tmp_path / "explicit"
    monkeypatch.setenv("ASSETPIPE_CACHE", "")
    assert default_cache_dir() == tmp_path / "xdg" / "assetpipe"
    monkeypatch.delenv("ASSETPIPE_CACHE")
    assert default_cache_dir() == tmp_path / "xdg" / "assetpipe"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "assetpipe"
    monkeypatch.setenv("XDG_CACHE_HOME", "")
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "assetpipe"


def test_relative_xdg_cache_home_is_ignored(monkeypatch, tmp_path):
    # the XDG base directory spec: a relative path in XDG_CACHE_HOME is invalid and ignored
    monkeypatch.delenv("ASSETPIPE_CACHE")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "assetpipe"
    assert Path(default_cache_dir()).is_absolute()


def test_a_cache_folder_deleted_while_the_process_runs_is_made_again(tmp_path):
    import shutil

    from assetpipe.cache.store import Store

    s = Store(tmp_path / "c")
    d1 = s.put_blob(b"one")
    shutil.rmtree(tmp_path / "c")  # e.g. the user cleared the cache during a long build
    s2 = Store(tmp_path / "c")  # the process remembers the folders it made: they must come back
    d2 = s2.put_blob(b"two")
    assert s2.get_blob(d2) == b"two" and s2.get_blob(d1) is None


def test_export_blob_never_lets_an_output_edit_reach_the_blob(tmp_path):
    store = Store(tmp_path / "cache")
    d = store.put_blob(b"vertex bytes")
    assert store.blob_path(d).stat().st_mode & 0o777 == 0o444
    out = tmp_path / "out"
    out.mkdir()
    how = store.export_blob(d, out / "a.vtx", out)
    assert how in ("reflink", "copy")  # the default: never the blob's own inode
    assert (out / "a.vtx").stat().st_ino != store.blob_path(d).stat().st_ino
    (out / "a.vtx").write_bytes(b"edited in place")  # open(..., "w"): the same inode
    assert store.get_blob(d) == b"vertex bytes" and store.dropped == []


def test_export_blob_hardlinks_only_when_asked_and_only_once(tmp_path, monkeypatch):
    monkeypatch.setenv("ASSETPIPE_OUTPUT_LINKS", "hardlink")
    store = Store(tmp_path / "cache")
    d = store.put_blob(b"texture bytes")
    (tmp_path / "o1").mkdir()
    (tmp_path / "o2").mkdir()
    assert store.export_blob(d, tmp_path / "o1" / "t.png", tmp_path / "o1") == "hardlink"
    assert (tmp_path / "o1" / "t.png").stat().st_ino == store.blob_path(d).stat().st_ino
    # a second output folder gets its own copy: a hand edit can reach at most one folder and the cache
    assert store.export_blob(d, tmp_path / "o2" / "t.png", tmp_path / "o2") in ("reflink", "copy")
    # and the cache never serves an edit made through the link: it is found and dropped
    os.chmod(tmp_path / "o1" / "t.png", 0o644)
    (tmp_path / "o1" / "t.png").write_bytes(b"edited")
    assert store.get_blob(d) is None and len(store.dropped) == 1
    with pytest.raises(FileNotFoundError, match=r"blob xxh3:[0-9a-f]+ for .*t2\.png vanished from the cache"):
        store.export_blob(d, tmp_path / "o2" / "t2.png", tmp_path / "o2")


def test_a_build_session_dropped_without_end_build_unregisters(tmp_path):
    store = Store(tmp_path / "cache")
    session = store.begin_build()
    path = session[1]
    assert path.exists()
    del session  # a build that raised: its frame, and the session, are dropped
    assert not path.exists() and list((tmp_path / "cache" / "builds").iterdir()) == []


def test_small_files_step_over_a_stale_temporary(store, monkeypatch):
    """The build's lookup record is written through a temporary named by the pid and a
    counter (not tempfile, which a no-op build does not import): one a killed process with
    the same pid left behind is stepped over, not overwritten, and the record lands whole."""
    import itertools

    monkeypatch.setattr(store_mod, "_SMALL_NAMES", itertools.count())
    store.root.mkdir(parents=True, exist_ok=True)
    stale = store.root / f".tmp-{os.getpid()}-0"
    stale.write_bytes(b"left by a killed build")
    store.hits, store.misses = 3, 1
    store.end_build(None, store.root.parent / "out", seconds=0.5)
    rec = json.loads((store.root / store_mod.LAST_BUILD).read_text())
    assert (rec["lookups"], rec["hits"], rec["seconds"]) == (4, 3, 0.5)
    assert stale.read_bytes() == b"left by a killed build"
    assert sorted(p.name for p in store.root.glob(".tmp-*")) == [stale.name]
