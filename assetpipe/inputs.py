"""Finding model files under the inputs, and giving each a unique id."""

from __future__ import annotations

import os
import re
from pathlib import Path

from assetpipe.core.errors import ConfigError

MODEL_SUFFIXES = (".gltf", ".glb", ".obj")


def _suffix(name: str) -> str:
    """The suffix by pathlib's rule, for files found in folders and files named alike
    (``os.path.splitext`` sees none in ``...obj``; pathlib sees ``.obj``)."""
    return Path(name).suffix.lower()


def _walk(folder: Path) -> list[Path]:
    """Model files under ``folder``, recursively, in sorted order. One scandir per folder and
    no stat per file (the directory entry's type says whether it is a file). A folder reached
    again (a link to a folder above it, two links to one folder) is walked once: a link to its
    own folder made the walk go 40 links deep and fail (two such links: 2^40 paths); an entry
    that cannot be examined is left out, as an unreadable folder is."""
    out: list[str] = []
    top = os.fspath(folder)
    seen = {_folder_key(top)}
    stack = [top]
    while stack:
        d = stack.pop()
        try:
            entries = list(os.scandir(d))
        except OSError:
            continue
        for e in entries:
            try:
                if e.is_dir():
                    key = _folder_key(e.path)
                    if key not in seen:
                        seen.add(key)
                        stack.append(e.path)
                elif _suffix(e.name) in MODEL_SUFFIXES and e.is_file():
                    out.append(e.path)
            except OSError:
                continue
    out.sort(key=lambda f: f.split(os.sep))
    return [Path(f) for f in out]


def _folder_key(path: str) -> tuple[int, int]:
    """(device, inode) of the folder ``path`` names, through links."""
    st = os.stat(path)
    return st.st_dev, st.st_ino


def discover_inputs(inputs: list[str | Path]) -> list[Path]:
    """Model files named or found (recursively, sorted) under named folders; no duplicates
    (two names of one file, through ``..`` or the current folder, count once)."""
    found: list[Path] = []
    for raw in inputs:
        p = Path(raw)
        if p.is_dir():
            found.extend(_walk(p))
        elif p.is_file():
            if p.suffix.lower() not in MODEL_SUFFIXES:
                raise ConfigError(f"{p}: not a model file (expected {', '.join(MODEL_SUFFIXES)})")
            found.append(p)
        else:
            raise ConfigError(f"{p}: no such file or folder")
    seen, out = set(), []
    for f in found:
        key = os.path.abspath(f)
        if key not in seen:
            seen.add(key)
            out.append(f)
    return out


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def assign_ids(sources: list[Path]) -> dict[Path, str]:
    """A unique, file-name-safe id per source: its stem, qualified by parent folders on clashes.

    Deterministic for a given set of inputs: ``a/Box.gltf`` and ``b/Box.gltf`` become
    ``a_Box`` and ``b_Box``; no folder tells ``m/Box.gltf`` and ``m/Box.obj`` apart, so their
    suffix does: ``Box_gltf`` and ``Box_obj``.
    """
    # stems shared (case-insensitively) by several files of one folder take their suffix
    parent = {p: Path(os.path.abspath(p)).parent for p in sources}
    by_folder: dict[tuple, int] = {}
    for p in sources:
        k = (parent[p], p.stem.lower())
        by_folder[k] = by_folder.get(k, 0) + 1
    def safe(text: str) -> str:
        # [A-Za-z0-9._-] only, never starting or ending with '.' or '_' (so never '', '.', '..'
        # or a hidden file name)
        return _UNSAFE.sub("_", text).strip("_.") or "model"

    name = {p: safe(f"{p.stem}_{p.suffix[1:]}" if by_folder[(parent[p], p.stem.lower())] > 1 else p.stem)
            for p in sources}

    def candidate(p: Path, depth: int) -> str:
        parts = [*parent[p].parts[len(parent[p].parts) - depth:], name[p]] if depth else [name[p]]
        return safe("_".join(parts))

    depth = {p: 0 for p in sources}
    while True:
        ids = {p: candidate(p, depth[p]) for p in sources}
        clashes: dict[str, list[Path]] = {}
        for p, i in ids.items():
            clashes.setdefault(i.lower(), []).append(p)
        dup = [ps for ps in clashes.values() if len(ps) > 1]
        if not dup:
            return ids
        progressed = False
        for ps in dup:
            for p in ps:
                if depth[p] < len(parent[p].parts):
                    depth[p] += 1
                    progressed = True
        if not progressed:  # names differing only in case, in one folder: number them, start over
            for ps in dup:
                for n, p in enumerate(sorted(ps)):
                    name[p] = f"{name[p]}_{n}"
            depth = {p: 0 for p in sources}


