"""Atomic output writes and the sweep of temporaries left by killed builds."""

from __future__ import annotations

import os
import stat
import time

import numpy as np
import pytest

from assetpipe.core import writer
from assetpipe.core.writer import WRITE_CHUNK, STATE_DIR, sweep_tmp, tmp_dir, write_all, write_atomic


def test_write_creates_folders_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "out" / "sub" / "M.idx"
    data = os.urandom(100_000)
    write_atomic(p, data)
    assert p.read_bytes() == data
    assert sorted(os.listdir(p.parent)) == ["M.idx"]
    assert stat.S_IMODE(p.stat().st_mode) == 0o644


def test_write_through_the_state_tmp_folder(tmp_path):
    t = tmp_dir(tmp_path)
    assert t == tmp_path / STATE_DIR / "tmp" and t.is_dir()
    write_atomic(tmp_path / "M.json", b"{}\n", t)
    assert (tmp_path / "M.json").read_bytes() == b"{}\n"
    assert list(t.iterdir()) == []


def test_overwrite_replaces_the_content_completely(tmp_path):
    p = tmp_path / "M.vtx"
    write_atomic(p, b"a much longer old content")
    write_atomic(p, b"new")
    assert p.read_bytes() == b"new"
    write_atomic(p, b"")
    assert p.read_bytes() == b""


@pytest.mark.parametrize("exc", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_failed_replace_keeps_the_old_file_and_removes_the_temporary(tmp_path, monkeypatch, exc):
    p = tmp_path / "M.json"
    p.write_bytes(b"old")
    t = tmp_dir(tmp_path)
    seen = []

    def boom(src, dst):
        seen.append(src)
        assert open(src, "rb").read() == b"new content"  # the temporary was complete
        raise exc

    monkeypatch.setattr(writer.os, "replace", boom)
    with pytest.raises(type(exc)):
        write_atomic(p, b"new content", t)
    assert p.read_bytes() == b"old"
    assert len(seen) == 1 and not os.path.exists(seen[0])
    assert list(t.iterdir()) == [] and sorted(os.listdir(tmp_path)) == [STATE_DIR, "M.json"]


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    p = tmp_path / "M.json"
    p.write_bytes(b"old")

    def bad_chmod(*args):  # fails between writing the temporary and renaming it
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(writer.os, "chmod", bad_chmod)
    with pytest.raises(OSError, match="Input/output error"):
        write_atomic(p, b"new")
    assert p.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["M.json"]


def test_sweep_removes_only_old_temporaries(tmp_path):
    t = tmp_dir(tmp_path)
    old, young, edge = t / "old.tmp", t / "young.tmp", t / "edge.tmp"
    for p in (old, young, edge):
        p.write_bytes(b"x")
    now = time.time()
    os.utime(old, (now - 7200, now - 7200))
    os.utime(edge, (now - 3000, now - 3000))
    keep = tmp_path / "M.json"  # outputs outside the tmp folder are never swept
    keep.write_bytes(b"x")
    os.utime(keep, (now - 99999, now - 99999))
    sweep_tmp(tmp_path)
    assert sorted(p.name for p in t.iterdir()) == ["edge.tmp", "young.tmp"]
    assert keep.exists()
    sweep_tmp(tmp_path, older_than_s=600)
    assert sorted(p.name for p in t.iterdir()) == ["young.tmp"]


def test_sweep_without_a_tmp_folder_does_nothing(tmp_path):
    sweep_tmp(tmp_path)
    sweep_tmp(tmp_path / "missing")
    assert not (tmp_path / STATE_DIR).exists()


def test_sweep_survives_a_subfolder(tmp_path):
    t = tmp_dir(tmp_path)
    (t / "dir").mkdir()
    os.utime(t / "dir", (0, 0))
    (t / "f").write_bytes(b"")
    os.utime(t / "f", (0, 0))
    sweep_tmp(tmp_path)
    assert [p.name for p in t.iterdir()] == ["dir"]


@pytest.mark.parametrize("size", [0, 1, WRITE_CHUNK - 1, WRITE_CHUNK, 3 * WRITE_CHUNK + 17])
def test_write_all_writes_every_byte_in_order(tmp_path, size):
    """Slices of WRITE_CHUNK bytes, the last one short: the file holds the bytes as given, for
    bytes, a bytearray and a numpy array alike (what write_atomic and the store hand it)."""
    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8)
    for i, given in enumerate((data.tobytes(), bytearray(data.tobytes()), data)):
        path = tmp_path / f"{i}.bin"
        with open(path, "wb") as f:
            write_all(f, given)
        assert path.read_bytes() == data.tobytes()
