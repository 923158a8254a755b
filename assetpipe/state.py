"""What the last build wrote into an output folder, and the no-op check against it.

``OUT/.assetpipe/state.json`` holds, per source (absolute path): its id, the digests of every
file its build read, and every output it owns (path relative to OUT, blob digest, size,
mtime_ns). ``OUT/.assetpipe/explain.json`` holds the last key inputs of every step, read only
to explain why a step reruns. Both are written atomically at the end of a build.

The no-op path runs on this module, the stat cache and xxhash only: no numpy, no pillow, no
importer, no renderer.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from assetpipe.core.errors import ConfigError
from assetpipe.core.hashing import digest_file
from assetpipe.core.json_shape import is_int, strings
from assetpipe.core.state_file import read_json_dict as _read_json
from assetpipe.core.state_file import source_of  # noqa: F401 (re-exported)
from assetpipe.core.writer import STATE_DIR, tmp_dir, write_atomic

STATE_VERSION = 1


def confined_rel(rel) -> bool:
    """True when ``rel`` (read from a state file) names a path inside the output folder.

    A state file can come from elsewhere (an output folder restored from CI artifacts, or
    shared), so every output path in it is checked before it is stat'ed, written or deleted:
    a relative POSIX path of plain parts: no ``..``, ``.`` or empty part, no root, no NUL."""
    if not isinstance(rel, str) or not rel or "\0" in rel or os.path.isabs(rel):
        return False
    parts = rel.split("/")
    return all(part not in ("", ".", "..") for part in parts)


def _output_ok(value) -> bool:
    """An output's record: [blob digest, size, mtime_ns]."""
    return isinstance(value, list) and len(value) == 3 and isinstance(value[0], str) and all(map(is_int, value[1:]))


def _entry_ok(entry) -> bool:
    """An entry of the shape a build writes, every output inside OUT (a value of another type
    raised from the no-op check or the report and failed the whole build)."""
    return (isinstance(entry, dict) and isinstance(entry.get("outputs"), dict)
            and isinstance(entry.get("inputs"), dict)
            and all(confined_rel(rel) and _output_ok(v) for rel, v in entry["outputs"].items())
            and all(isinstance(d, str) for d in entry["inputs"].values())
            and isinstance(entry.get("id"), str) and isinstance(entry.get("options"), str)
            and strings(entry.get("warnings", [])) and strings(entry.get("skipped", []))
            and isinstance(entry.get("stats", {}), dict)
            and (entry.get("scenes") is None or strings(entry["scenes"]))
            and isinstance(entry.get("source", ""), str))


class OutputState:
    def __init__(self, out_dir: Path):
        self.out_dir = Path(out_dir)
        self.path = self.out_dir / STATE_DIR / "state.json"
        data = _read_json(self.path)
        if data.get("version") != STATE_VERSION:
            data = {}
        assets = data.get("assets", {})
        # entries damaged by hand, or naming an output outside OUT, are dropped (their sources
        # simply rebuild, and nothing outside OUT is ever stat'ed, written or deleted for them)
        self.assets: dict[str, dict] = {k: e for k, e in (assets.items() if isinstance(assets, dict) else [])
                                        if _entry_ok(e)}
        self._owned_at_load = {rel for e in self.assets.values() for rel in e.get("outputs", {})}
        self.touched = False

    def load_explain(self) -> dict:
        data = _read_json(self.out_dir / STATE_DIR / "explain.json")
        return data.get("steps", {}) if data.get("version") == STATE_VERSION else {}

    def save(self, explain_steps: dict | None) -> None:
        body = {"version": STATE_VERSION, "assets": self.assets}
        tmp = tmp_dir(self.out_dir)
        write_atomic(self.path, json.dumps(body, separators=(",", ":"), sort_keys=True).encode(), tmp)
        if explain_steps is not None:
            write_atomic(self.out_dir / STATE_DIR / "explain.json",
                         json.dumps({"version": STATE_VERSION, "steps": explain_steps},
                                    separators=(",", ":"), sort_keys=True).encode(), tmp)

    # -- the no-op check ----------------------------------------------------------------
    def check(self, source: Path, model_id: str, options_digest: str, stat_cache) -> str | None:
        """None when ``source``'s outputs are up to date; otherwise why not."""
        return self.check_entry(os.path.abspath(source), model_id, options_digest, stat_cache)

    def check_entry(self, key: str, model_id: str, options_digest: str, stat_cache) -> str | None:
        """None when the outputs of state entry ``key`` are up to date; otherwise why not."""
        entry = self.assets.get(key)
        if entry is None:
            return "new"
        if not isinstance(entry.get("inputs"), dict) or not isinstance(entry.get("outputs"), dict):
            return "state entry incomplete"
        if entry.get("options") != options_digest:
            return "options or versions changed"
        if entry.get("id") != model_id:
            return f"id changed ({entry.get('id')} -> {model_id})"
        for path, digest in entry["inputs"].items():
            try:
                if stat_cache.digest_abs(path) != digest:
                    return f"input changed: {os.path.basename(path)}"
            except FileNotFoundError:
                return f"input missing: {os.path.basename(path)}"
        prefix = os.path.join(os.fspath(self.out_dir), "")
        for rel, (digest, size, mtime_ns) in entry["outputs"].items():
            p = prefix + rel
            try:
                st = os.stat(p)
            except FileNotFoundError:
                return f"output missing: {rel}"
            if st.st_size == size and st.st_mtime_ns == mtime_ns:
                continue
            if st.st_size != size or digest_file(p) != digest:
                return f"output modified: {rel}"
            entry["outputs"][rel] = [digest, st.st_size, st.st_mtime_ns]  # touched, same bytes
            self.touched = True  # remember the new mtime, so the next no-op reads nothing
        return None

    # -- after a build ------------------------------------------------------------------
    def materialise(self, store, outputs: dict[str, str], previous: dict | None) -> tuple[dict, list[str]]:
        """Put every output (OUT path -> blob digest) in place; returns the new output table
        and notes on outputs restored because they were missing or modified."""
        table, notes = {}, []
        prev = (previous or {}).get("outputs", {})
        tmp = tmp_dir(self.out_dir)
        root = os.path.realpath(self.out_dir)
        for rel in sorted(outputs):
            digest = outputs[rel]
            p = self.out_dir / rel
            # nothing is written outside OUT: not a path that leaves it, nor through a link in it
            if not confined_rel(rel) or os.path.commonpath([root, os.path.realpath(p.parent)]) != root:
                raise ConfigError(f"output {rel} would be written outside {self.out_dir} "
                                  "(a link in the output folder leads out of it): refused")
            try:
                st = os.stat(p)
                same = (prev.get(rel, [None])[0] == digest and st.st_size == prev[rel][1]
                        and st.st_mtime_ns == prev[rel][2]) or digest_file(p) == digest
                if same:
                    table[rel] = [digest, st.st_size, st.st_mtime_ns]
                    continue
                if rel in prev and prev[rel][0] == digest:
                    notes.append(f"output modified, restored: {rel}")
            except FileNotFoundError:
                if rel in prev:
                    notes.append(f"output missing, restored: {rel}")
            p.parent.mkdir(parents=True, exist_ok=True)
            store.export_blob(digest, p, tmp)  # a hard link to the blob where possible, else a copy
            st = os.stat(p)
            table[rel] = [digest, st.st_size, st.st_mtime_ns]
        return table, notes

    def forget_missing_sources(self) -> list[str]:
        """Drop the entries of sources that no longer exist (deleted or renamed); their ids."""
        gone = [k for k, e in self.assets.items() if not os.path.exists(e.get("source", k))]
        return [self.assets.pop(k)["id"] for k in gone]

    def forget_entries(self, keys) -> None:
        for k in keys:
            self.assets.pop(k, None)

    def delete_unowned_outputs(self) -> list[str]:
        """Delete outputs the state owned when loaded and no entry owns now."""
        owned = {rel for e in self.assets.values() for rel in e["outputs"]}
        removed = []
        root = os.path.realpath(self.out_dir)
        for rel in sorted(self._owned_at_load - owned):
            p = self.out_dir / rel
            # a link inside OUT must not carry a deletion outside it either
            if os.path.commonpath([root, os.path.realpath(p.parent)]) != root:
                continue
            try:
                p.unlink()
                removed.append(rel)
            except FileNotFoundError:
                pass
        return removed
