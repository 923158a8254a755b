"""Output state: the stat-only no-op check, materialising outputs, and removing stale ones."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from assetpipe.core.hashing import digest_bytes, digest_file
from assetpipe.state import OutputState, source_of
from assetpipe.core.writer import STATE_DIR
from assetpipe.cache.stat_cache import StatCache
from assetpipe.cache.store import Store

OLD = time.time_ns() - 3600 * 1_000_000_000


class _Env:
    """An output folder, a store, and sources whose 'builds' are plain byte strings."""

    def __init__(self, root: Path):
        self.root = root
        self.out = root / "out"
        self.src_dir = root / "src"
        self.src_dir.mkdir()
        self.store = Store(root / "cache")

    def source(self, name: str, data: bytes = b"model") -> Path:
        p = self.src_dir / name
        p.write_bytes(data)
        os.utime(p, ns=(OLD, OLD))
        return p

    def build(self, state: OutputState, src: Path, model_id: str, outputs: dict[str, bytes],
              inputs: list[Path] | None = None, options: str = "opt"):
        digests = {rel: self.store.put_blob(data) for rel, data in outputs.items()}
        key = str(src.resolve())
        table, notes = state.materialise(self.store, digests, state.assets.get(key))
        state.assets[key] = {"id": model_id, "options": options,
                             "inputs": {str(p.resolve()): digest_file(p) for p in (inputs or [src])},
                             "outputs": table}
        return notes


def _outputs(mid: str, tag: bytes = b"") -> dict[str, bytes]:
    return {f"{mid}.json": b"{json " + mid.encode() + tag + b"}", f"{mid}.idx": b"idx" + tag,
            "textures/shared.png": b"PNG shared"}


@pytest.fixture
def env(tmp_path) -> _Env:
    return _Env(tmp_path)


def _built(env: _Env):
    src = env.source("a.gltf")
    dep = env.source("a.bin", b"buffer")
    state = OutputState(env.out)
    env.build(state, src, "A", _outputs("A"), inputs=[src, dep])
    state.save(None)
    return src, dep, OutputState(env.out)


def _check(state, src, mid="A", opt="opt"):
    return state.check(src, mid, opt, StatCache(None))


# -- check --------------------------------------------------------------------------------------

def test_check_new(env):
    assert _check(OutputState(env.out), env.source("a.gltf")) == "new"


def test_check_up_to_date(env):
    src, _, state = _built(env)
    assert _check(state, src) is None


def test_check_up_to_date_reads_no_output(env, monkeypatch):
    src, _, state = _built(env)
    import assetpipe.state as st
    monkeypatch.setattr(st, "digest_file", lambda p: pytest.fail(f"read {p}"))
    assert _check(state, src) is None


def test_check_options_changed(env):
    src, _, state = _built(env)
    assert _check(state, src, opt="other") == "options or versions changed"


def test_check_id_changed(env):
    src, _, state = _built(env)
    assert _check(state, src, mid="B") == "id changed (A -> B)"


def test_check_input_changed(env):
    src, dep, state = _built(env)
    dep.write_bytes(b"other buffer")
    assert _check(state, src) == "input changed: a.bin"


def test_check_input_missing(env):
    src, dep, state = _built(env)
    dep.unlink()
    assert _check(state, src) == "input missing: a.bin"


def test_check_output_missing(env):
    src, _, state = _built(env)
    (env.out / "A.idx").unlink()
    assert _check(state, src) == "output missing: A.idx"


def test_check_output_modified_same_size(env):
    src, _, state = _built(env)
    p = env.out / "A.idx"
    p.write_bytes(b"IDX")
    assert _check(state, src) == "output modified: A.idx"


def test_check_output_modified_size(env):
    src, _, state = _built(env)
    (env.out / "textures" / "shared.png").write_bytes(b"PNG shared, edited")
    assert _check(state, src) == "output modified: textures/shared.png"


def test_check_touched_but_identical_output_accepted_and_mtime_updated(env):
    src, _, state = _built(env)
    p = env.out / "A.json"
    os.utime(p, ns=(OLD, OLD))
    entry = state.assets[str(src.resolve())]
    assert entry["outputs"]["A.json"][2] != OLD
    assert _check(state, src) is None
    assert entry["outputs"]["A.json"] == [digest_bytes(b"{json A}"), p.stat().st_size, OLD]


# -- materialise --------------------------------------------------------------------------------

def test_materialise_writes_every_output(env):
    src = env.source("a.gltf")
    state = OutputState(env.out)
    notes = env.build(state, src, "A", _outputs("A"))
    assert notes == []
    for rel, data in _outputs("A").items():
        assert (env.out / rel).read_bytes() == data
        d, size, mtime = state.assets[str(src.resolve())]["outputs"][rel]
        st = (env.out / rel).stat()
        assert (d, size, mtime) == (digest_bytes(data), st.st_size, st.st_mtime_ns)
    assert list((env.out / STATE_DIR / "tmp").iterdir()) == []


def test_materialise_restores_missing_and_modified_and_leaves_identical_untouched(env):
    src, _, state = _built(env)
    (env.out / "A.idx").unlink()
    (env.out / "A.json").write_bytes(b"hand edited")
    shared = env.out / "textures" / "shared.png"
    os.utime(shared, ns=(OLD, OLD))  # touched, same bytes
    ino = shared.stat().st_ino
    notes = env.build(state, src, "A", _outputs("A"))
    assert notes == ["output missing, restored: A.idx", "output modified, restored: A.json"]
    for rel, data in _outputs("A").items():
        assert (env.out / rel).read_bytes() == data
    assert shared.stat().st_ino == ino and shared.stat().st_mtime_ns == OLD
    assert state.assets[str(src.resolve())]["outputs"]["textures/shared.png"][2] == OLD


def test_materialise_new_content_is_not_a_restore(env):
    src, _, state = _built(env)
    notes = env.build(state, src, "A", _outputs("A", b" v2"))
    assert notes == []
    assert (env.out / "A.idx").read_bytes() == b"idx v2"


def test_materialise_missing_blob_is_an_error(env):
    state = OutputState(env.out)
    with pytest.raises(FileNotFoundError, match=r"blob xxh3:[0-9a-f]+ for .*A\.json vanished from the cache"):
        state.materialise(env.store, {"A.json": digest_bytes(b"never stored")}, None)


# -- stale outputs ------------------------------------------------------------------------------

def test_deleted_source_outputs_removed_but_shared_texture_kept(env):
    a, b = env.source("a.gltf"), env.source("b.gltf", b"model b")
    state = OutputState(env.out)
    env.build(state, a, "A", _outputs("A"))
    env.build(state, b, "B", _outputs("B"))
    state.save(None)
    a.unlink()
    state = OutputState(env.out)
    assert state.forget_missing_sources() == ["A"]
    assert state.forget_missing_sources() == []
    removed = state.delete_unowned_outputs()
    assert removed == ["A.idx", "A.json"]
    assert not (env.out / "A.json").exists() and not (env.out / "A.idx").exists()
    for rel in _outputs("B"):
        assert (env.out / rel).exists()
    assert list(state.assets) == [str(b.resolve())]


def test_last_owner_gone_removes_shared_texture(env):
    a, b = env.source("a.gltf"), env.source("b.gltf", b"model b")
    state = OutputState(env.out)
    env.build(state, a, "A", _outputs("A"))
    env.build(state, b, "B", _outputs("B"))
    state.save(None)
    a.unlink(), b.unlink()
    state = OutputState(env.out)
    assert sorted(state.forget_missing_sources()) == ["A", "B"]
    assert state.delete_unowned_outputs() == ["A.idx", "A.json", "B.idx", "B.json", "textures/shared.png"]


def test_output_no_longer_produced_is_removed(env):
    src, _, state = _built(env)
    outs = _outputs("A")
    outs.pop("textures/shared.png")
    outs["textures/new.png"] = b"PNG new"
    env.build(state, src, "A", outs)
    assert state.forget_missing_sources() == []
    assert state.delete_unowned_outputs() == ["textures/shared.png"]
    assert (env.out / "textures" / "new.png").exists()


def test_unknown_files_in_out_are_never_deleted(env):
    src, _, state = _built(env)
    (env.out / "mine.txt").write_bytes(b"user file")
    src.unlink()
    state = OutputState(env.out)
    state.forget_missing_sources()
    state.delete_unowned_outputs()
    assert (env.out / "mine.txt").exists()


def test_renamed_source_is_a_new_source_and_old_outputs_go(env):
    src, _, _ = _built(env)
    renamed = src.with_name("c.gltf")
    src.rename(renamed)
    state = OutputState(env.out)
    assert _check(state, renamed, mid="C") == "new"
    env.build(state, renamed, "C", _outputs("C"))
    assert state.forget_missing_sources() == ["A"]
    assert state.delete_unowned_outputs() == ["A.idx", "A.json"]
    assert (env.out / "textures" / "shared.png").exists()


# -- persistence --------------------------------------------------------------------------------

def test_save_load_and_source_of(env):
    src, _, state = _built(env)
    assert source_of(env.out, "A") == src.resolve()
    assert source_of(env.out, "Z") is None
    assert source_of(env.root / "nowhere", "A") is None
    state.save({"k": {"step": 1}})
    again = OutputState(env.out)
    assert again.assets == state.assets
    assert again.load_explain() == {"k": {"step": 1}}
    assert list((env.out / STATE_DIR / "tmp").iterdir()) == []


@pytest.mark.parametrize("content", [b"", b"{broken", b"[]", b'{"version": 99, "assets": {"x": {}}}'])
def test_unreadable_state_is_empty(env, content):
    (env.out / STATE_DIR).mkdir(parents=True)
    (env.out / STATE_DIR / "state.json").write_bytes(content)
    (env.out / STATE_DIR / "explain.json").write_bytes(content)
    state = OutputState(env.out)
    assert state.assets == {} and state.load_explain() == {}
    assert state.delete_unowned_outputs() == []
    assert source_of(env.out, "x") is None


def test_damaged_state_entry_is_rebuilt_not_a_crash(env):
    src = env.source("a.gltf")
    (env.out / STATE_DIR).mkdir(parents=True)
    (env.out / STATE_DIR / "state.json").write_text(
        json.dumps({"version": 1, "assets": {str(src.resolve()): {"id": "A", "options": "opt"}}}))
    state = OutputState(env.out)
    assert state.assets == {}  # an entry without inputs or outputs is dropped on load
    assert _check(state, src) == "new"  # so its source rebuilds from scratch
    assert state.delete_unowned_outputs() == []


# -- confinement: a crafted or restored state file never reaches outside OUT ----------------------

@pytest.mark.parametrize("rel", ["../victim.txt", "ABSOLUTE", "textures/../../victim.txt", "./A.json",
                                 "a//b", "", "a\0b"])
def test_state_naming_an_output_outside_out_is_dropped_and_nothing_outside_is_deleted(env, rel):
    victim = env.root / "victim.txt"
    victim.write_bytes(b"precious")
    src = env.source("a.gltf")
    if rel == "ABSOLUTE":
        rel = str(victim)
    (env.out / STATE_DIR).mkdir(parents=True)
    entry = {"id": "A", "options": "opt", "inputs": {str(src.resolve()): digest_file(src)},
             "outputs": {rel: [digest_bytes(b"x"), 1, 1], "A.json": [digest_bytes(b"y"), 1, 1]}}
    (env.out / STATE_DIR / "state.json").write_text(json.dumps({"version": 1, "assets": {str(src.resolve()): entry}}))
    state = OutputState(env.out)
    assert state.assets == {}  # the whole entry is distrusted: its source rebuilds
    assert _check(state, src) == "new"
    src.unlink()
    state.forget_missing_sources()
    assert state.delete_unowned_outputs() == []
    assert victim.read_bytes() == b"precious"


def test_stale_output_behind_a_link_out_of_out_is_not_deleted(env):
    outside = env.root / "elsewhere"
    outside.mkdir()
    (outside / "A.json").write_bytes(b"precious")
    src = env.source("a.gltf")
    state = OutputState(env.out)
    env.build(state, src, "A", {"sub/A.json": b"json"})
    state.save(None)
    (env.out / "sub" / "A.json").unlink()
    (env.out / "sub").rmdir()
    (env.out / "sub").symlink_to(outside)  # OUT/sub now leads outside OUT
    src.unlink()
    state = OutputState(env.out)
    assert state.forget_missing_sources() == ["A"]
    assert state.delete_unowned_outputs() == []
    assert (outside / "A.json").read_bytes() == b"precious"


def test_an_entry_of_another_shape_is_dropped_and_its_source_rebuilds(env):
    # every value of a saved state replaced in turn by "x", -1, null, [] or {}: the state loads,
    # the no-op check answers (an entry of another shape is dropped: "new"), nothing raises (an
    # output record that was a string failed the whole build on unpacking; a number for the
    # warnings, on the report); a sound entry still checks up to date
    from tests.json_edits import value_paths, with_value

    src, _, state = _built(env)
    assert _check(state, src) is None
    doc = json.loads(state.path.read_text())
    outcomes = set()
    for where in value_paths(doc):
        for value in ("x", -1, None, [], {}):
            state.path.write_text(json.dumps(with_value(doc, where, value)))
            loaded = OutputState(env.out)
            for key, entry in loaded.assets.items():
                list(entry.get("warnings", [])), list(entry.get("skipped", []))  # what a cached result reads
            outcomes.add(_check(loaded, src))
            loaded.delete_unowned_outputs()
            assert (env.out / "A.json").is_file()  # a damaged state never costs a good output
    assert "new" in outcomes and None in outcomes
