"""The stat cache: unchanged files are not re-read, changed ones are, racily clean ones are not kept."""

from __future__ import annotations

import json
import os
import time

import pytest

from assetpipe.core.hashing import digest_bytes
from assetpipe.cache import stat_cache as sc
from assetpipe.cache.stat_cache import StatCache

OLD = time.time_ns() - 60 * 1_000_000_000  # an mtime safely outside the racy window


def _file(path, data: bytes, mtime_ns: int | None = OLD):
    path.write_bytes(data)
    if mtime_ns is not None:
        os.utime(path, ns=(mtime_ns, mtime_ns))
    return path


def test_digest_and_unchanged_file_not_reread(tmp_path):
    f = _file(tmp_path / "a.bin", b"hello")
    c = StatCache(tmp_path / "stat.json")
    assert c.digest(f) == digest_bytes(b"hello")
    assert c.hashed == 1
    for _ in range(3):
        assert c.digest(f) == digest_bytes(b"hello")
    assert c.hashed == 1
    # a relative spelling is the same entry
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        assert c.digest("a.bin") == digest_bytes(b"hello")
    finally:
        os.chdir(cwd)
    assert c.hashed == 1 and list(c.entries) == [str(f)]


def test_cached_digest_is_trusted_while_stat_matches(tmp_path):
    # same size and mtime (and inode): the stat cache cannot see a change, by design
    f = _file(tmp_path / "a.bin", b"aaaa")
    c = StatCache(None)
    c.digest(f)
    _file(f, b"bbbb", OLD)
    assert c.digest(f) == digest_bytes(b"aaaa") and c.hashed == 1


def test_changed_size_is_rehashed(tmp_path):
    f = _file(tmp_path / "a.bin", b"aaaa")
    c = StatCache(None)
    c.digest(f)
    _file(f, b"aaaaa", OLD)
    assert c.digest(f) == digest_bytes(b"aaaaa") and c.hashed == 2


def test_changed_mtime_is_rehashed(tmp_path):
    f = _file(tmp_path / "a.bin", b"aaaa")
    c = StatCache(None)
    c.digest(f)
    _file(f, b"bbbb", OLD + 1)
    assert c.digest(f) == digest_bytes(b"bbbb") and c.hashed == 2


def test_changed_inode_is_rehashed(tmp_path):
    f = _file(tmp_path / "a.bin", b"aaaa")
    c = StatCache(None)
    c.digest(f)
    # replaced by another file (an atomic save) with the same size and mtime
    g = _file(tmp_path / "b.bin", b"bbbb", OLD)
    os.replace(g, f)
    assert os.stat(f).st_mtime_ns == OLD
    assert c.digest(f) == digest_bytes(b"bbbb") and c.hashed == 2


def test_racily_clean_file_is_not_remembered(tmp_path):
    f = _file(tmp_path / "a.bin", b"fresh", mtime_ns=None)  # modified just now
    c = StatCache(tmp_path / "stat.json")
    assert c.digest(f) == digest_bytes(b"fresh")
    assert str(f) not in c.entries
    c.digest(f)
    assert c.hashed == 2  # read again: nothing was remembered
    # an old entry for it is forgotten when it turns racy
    os.utime(f, ns=(OLD, OLD))
    c.digest(f)
    assert str(f) in c.entries
    _file(f, b"fresh!", mtime_ns=None)
    assert c.digest(f) == digest_bytes(b"fresh!")
    assert str(f) not in c.entries


def test_racy_window_boundary(tmp_path, monkeypatch):
    f = _file(tmp_path / "a.bin", b"x")
    mtime = os.stat(f).st_mtime_ns
    c = StatCache(None)
    monkeypatch.setattr(sc.time, "time_ns", lambda: mtime + sc.RACY_NS)  # exactly 2 s: still racy
    c.digest(f)
    assert c.entries == {}
    monkeypatch.setattr(sc.time, "time_ns", lambda: mtime + sc.RACY_NS + 1)
    c.digest(f)
    assert list(c.entries) == [str(f)]


def test_missing_file_raises(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope"):
        StatCache(None).digest(tmp_path / "nope")


def test_save_load_round_trip(tmp_path):
    f = _file(tmp_path / "a.bin", b"abc")
    g = _file(tmp_path / "b.bin", b"defg")
    path = tmp_path / "sub" / "stat.json"
    c = StatCache(path)
    c.digest(f), c.digest(g)
    c.save()
    assert not c.dirty
    assert [p.name for p in path.parent.iterdir()] == ["stat.json"]  # no temporary left
    d = StatCache(path)
    assert d.entries == c.entries
    assert d.digest(f) == digest_bytes(b"abc") and d.digest(g) == digest_bytes(b"defg")
    assert d.hashed == 0
    assert not d.dirty


def test_save_only_when_dirty(tmp_path):
    path = tmp_path / "stat.json"
    c = StatCache(path)
    c.save()
    assert not path.exists()
    StatCache(None).save()  # no path: nothing to do


@pytest.mark.parametrize("content", [
    b"", b"{not json", b"\xff\xfe", b"[]", b"null", b"42", b'"text"',
    b'{"version": 99, "entries": {}}',
    b'{"version": 1}',
    b'{"version": 1, "entries": []}',
    b'{"version": 1, "entries": "x"}',
    b'{"version": 1, "entries": {"PATH": 5}}',
    b'{"version": 1, "entries": {"PATH": [1, 2]}}',
    b'{"version": 1, "entries": {"PATH": null}}',
])
def test_corrupt_stat_cache_file_is_ignored(tmp_path, content):
    f = _file(tmp_path / "a.bin", b"abc")
    path = tmp_path / "stat.json"
    path.write_bytes(content.replace(b"PATH", str(f).encode()))
    c = StatCache(path)
    assert c.digest(f) == digest_bytes(b"abc")
    assert c.hashed == 1
    c.save()
    assert json.loads(path.read_bytes())["entries"][str(f)][3] == digest_bytes(b"abc")


def test_unwritable_stat_cache_location_costs_nothing_but_time(tmp_path):
    (tmp_path / "blocker").write_bytes(b"")
    c = StatCache(tmp_path / "blocker" / "stat.json")  # its folder is a file
    f = _file(tmp_path / "a.bin", b"abc")
    c.digest(f)
    c.save()  # must not raise: a lost stat cache only costs re-reading files
    assert not (tmp_path / "blocker").is_dir()


def test_stat_matches(tmp_path):
    f = _file(tmp_path / "a.bin", b"abc")
    st = os.stat(f)
    c = StatCache(None)
    assert c.stat_matches(f, st.st_size, st.st_mtime_ns)
    assert not c.stat_matches(f, st.st_size + 1, st.st_mtime_ns)
    assert not c.stat_matches(f, st.st_size, st.st_mtime_ns + 1)
    assert not c.stat_matches(tmp_path / "nope", 0, 0)
