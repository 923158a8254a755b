"""Wavefront OBJ + MTL importer: ``import_obj(path) -> ImportedModel``.

Parsing is vectorised: the file is classified line by line with numpy byte operations (no
Python loop over the ``v``/``vt``/``vn``/``f`` lines); the numbers of each statement kind are
parsed in one C call, and only the rare other statements (``o``, ``g``, ``usemtl``,
``mtllib``, ...) are looked at from Python.

What the importer does
----------------------
* ``v x y z [w]`` and ``v x y z r g b`` (vertex colours, kept as ``colors``), ``vt u [v [w]]``,
  ``vn``; ``f`` in the forms ``v``, ``v/vt``, ``v//vn``, ``v/vt/vn``; negative (relative)
  indices; ``#`` comments, CRLF, ``\\`` line continuations, UTF-8 with or without BOM and
  UTF-16 with BOM.
* Polygons are triangulated with :mod:`pipelines.triangulate` (concave ones correctly).
* One output vertex per distinct (v, vt, vn) triple within a mesh, so UV and normal seams
  stay split; vertices are numbered in order of first use.
* One :class:`MeshData` per distinct (object, group, material) combination, ordered by the
  first face that uses it (so an exporter that alternates ``usemtl`` per face does not make
  thousands of meshes). Meshes are named after the group, else the object, else the file.
* ``mtllib`` (several files, names with spaces), materials: see :mod:`pipelines.obj_mtl`.
* Texture and MTL paths are looked up only inside the model's folder (the .obj's folder):
  first as written (backslashes turned into slashes), relative to the MTL's folder and then
  the .obj's folder; then by file name anywhere under the model's folder (exact, then
  case-insensitive). Absolute paths go straight to the file-name search; a path escaping the
  folder is never read (warning).
* A missing MTL or texture is a warning, not an error: the model builds with the default
  material or without the texture. A texture file that exists but is not an image raises
  :class:`InvalidTextureError` (the user has to fix the file).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assetpipe.core.errors import AssetError, InvalidGeometryError
from assetpipe.core.rows import unique_rows
from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, InputBudgets
from assetpipe.pipelines.model import ImportedModel, MeshData
from assetpipe.pipelines.obj_mtl import Finder, ObjContext, load_materials
from assetpipe.pipelines.obj_text import (
    F,
    NL,
    OTHER,
    V,
    VN,
    VT,
    Lines,
    fast_decimals,
    parse_floats,
    parse_ints,
    ragged_to_matrix,
    read_normalised,
    token_layout,
)
from assetpipe.pipelines.triangulate import triangulate_polygons

__all__ = ["import_obj"]

# Stands for an absent vt/vn slot ("1//3", "1/2/") while parsing: never a real index.
_ABSENT = 1 << 62
_ABSENT_B = str(_ABSENT).encode()
# Bytes of face lines parsed at a time (whole lines): bounds the parsing temporaries, about
# 30 bytes per byte of face text.
_FACE_CHUNK_BYTES = 1 << 20

_FREEFORM = frozenset({"vp", "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm",
                       "trim", "hole", "scrv", "sp", "end", "con"})
_IGNORED = frozenset({"s", "mg", "usemap", "maplib", "shadow_obj", "trace_obj", "bevel",
                      "c_interp", "d_interp", "lod", "ctech", "stech", "call", "csh"})


# --------------------------------------------------------------------------------------
# The OBJ statements


@dataclass
class _Geometry:
    """The parsed numeric statements of one OBJ file."""

    positions: np.ndarray  # (NV, 3) float64
    colors: np.ndarray | None  # (NV, 4) float32 or None when no v line has a colour
    texcoords: np.ndarray  # (NT, 2) float64, as in the file (not flipped)
    normals: np.ndarray  # (NN, 3) float64
    v_lines: np.ndarray  # (NV,) int64 0-based line of each v
    # faces
    poly_line: np.ndarray  # (P,) 0-based line of each polygon
    poly_start: np.ndarray  # (P,) first corner of each polygon in the corner arrays
    poly_size: np.ndarray  # (P,) corners of each polygon
    corner_v: np.ndarray  # (C,) int64 0-based position index
    corner_vt: np.ndarray  # (C,) int64 0-based texcoord index, -1 if absent
    corner_vn: np.ndarray  # (C,) int64 0-based normal index, -1 if absent
    degenerate: int = 0  # triangle faces dropped because they name a vertex twice


def _numeric_lines(lines: Lines, path: Path, kind: int, keyword: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(values (K*?,) float64, counts per line (K,), line numbers (K,)) of one statement kind."""
    text, idx = lines.region(kind, len(keyword))
    arr = np.frombuffer(text, np.uint8)
    tok = token_layout(arr, idx.size)
    counts = tok.per_line
    values = fast_decimals(text, arr, tok)
    if values is None:
        values = parse_floats(text)
    if values is None or values.size != int(counts.sum()):
        _raise_bad_number(lines, path, idx, keyword)
    return values, counts, idx


def _raise_bad_number(lines: Lines, path: Path, idx: np.ndarray, keyword: str) -> None:
    for i in idx:
        tokens = lines.text(int(i)).split("#", 1)[0].split()[1:]
        for tok in tokens:
            try:
                float(tok)
            except ValueError:
                raise AssetError(path, f"line {i + 1}: {keyword!r} statement has a bad number {tok[:40]!r}") from None
    raise AssetError(path, f"cannot read the {keyword!r} statements")  # not reached in practice


def _parse_geometry(lines: Lines, path: Path, warnings: list[str],
                    budgets: InputBudgets = DEFAULT_INPUT_BUDGETS) -> _Geometry:
    # -- v
    values, counts, v_lines = _numeric_lines(lines, path, V, "v")
    if (counts < 3).any():
        bad = int(v_lines[np.argmax(counts < 3)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a vertex needs 3 coordinates")
    vmat = ragged_to_matrix(values, counts, 7, np.nan)
    positions = np.ascontiguousarray(vmat[:, :3])
    finite = np.isfinite(positions).all(axis=1)
    if not finite.all():
        k = int(np.argmin(finite))
        raise InvalidGeometryError(path, f"vertex {k + 1} (line {v_lines[k] + 1}) has a non-finite position")
    small = (np.abs(positions) <= budgets.max_coordinate).all(axis=1)
    if not small.all():
        k = int(np.argmin(small))
        raise InvalidGeometryError(path, f"vertex {k + 1} (line {v_lines[k] + 1}) has a coordinate beyond "
                                         f"+-{budgets.max_coordinate:g} (float32 arithmetic on it would overflow)")
    colors = None
    has_color = counts >= 6
    if has_color.any():
        # "x y z r g b" (6 values) or "x y z r g b a"-style 7 values: the last is ignored.
        colors = np.ones((positions.shape[0], 4), np.float32)
        with np.errstate(over="ignore"):  # a colour beyond float32 becomes inf: refused just below
            colors[has_color, :3] = vmat[has_color, 3:6]
        if not np.isfinite(colors).all():
            k = int(np.argmin(np.isfinite(colors).all(axis=1)))
            raise InvalidGeometryError(path, f"vertex {k + 1} (line {v_lines[k] + 1}) has a non-finite colour")
        if (counts == 7).any():
            warnings.append(f"{path.name}: vertices with 7 values: read as x y z r g b, the 7th value is ignored")
    # -- vt
    values, counts, vt_lines = _numeric_lines(lines, path, VT, "vt")
    if (counts < 1).any():
        bad = int(vt_lines[np.argmax(counts < 1)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a texture coordinate needs a value")
    texcoords = ragged_to_matrix(values, counts, 2, 0.0)
    ok = np.isfinite(texcoords).all(axis=1)
    if not ok.all():
        k = int(np.argmin(ok))
        raise InvalidGeometryError(path, f"texture coordinate {k + 1} (line {vt_lines[k] + 1}) is not finite")
    # -- vn
    values, counts, vn_lines = _numeric_lines(lines, path, VN, "vn")
    if (counts < 3).any():
        bad = int(vn_lines[np.argmax(counts < 3)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a normal needs 3 coordinates")
    normals = np.ascontiguousarray(ragged_to_matrix(values, counts, 3, 0.0))
    ok = np.isfinite(normals).all(axis=1)
    if not ok.all():
        k = int(np.argmin(ok))
        raise InvalidGeometryError(path, f"normal {k + 1} (line {vn_lines[k] + 1}) is not finite")

    # -- f, in chunks of whole lines so the parsing temporaries stay bounded (a 80 MB file of
    # 10M "f 1 1 1" lines took 3.84 GB parsed whole); degenerate triangles are dropped per chunk.
    text, f_lines = lines.region(F, 1)
    parts: list[tuple[np.ndarray, ...]] = []
    dropped = 0
    b0 = c0 = 0
    while b0 < len(text):  # a loop over chunks of megabytes, not lines
        b1 = b0 + _FACE_CHUNK_BYTES
        if b1 >= len(text):
            b1 = len(text)
        else:  # end on a line end: the last one in the chunk, else the first after it (a huge line)
            cut = text.rfind(b"\n", b0, b1)
            b1 = (cut if cut >= 0 else text.index(b"\n", b1)) + 1
        c1 = c0 + text.count(b"\n", b0, b1)
        part = _parse_faces(text[b0:b1], f_lines[c0:c1], v_lines, vt_lines, vn_lines, lines, path)
        dropped += part[-1]
        parts.append(part[:-1])
        b0, c0 = b1, c1
    del text
    if parts:
        per_line, corner_v, corner_vt, corner_vn, line_of = (np.concatenate(x) for x in zip(*parts))
        f_lines = line_of
    else:
        per_line = corner_v = corner_vt = corner_vn = np.zeros(0, np.int64)
        f_lines = np.zeros(0, np.int64)
    if dropped:
        warnings.append(f"{path.name}: {dropped} degenerate triangle face(s) ignored (a vertex used twice)")

    poly_start = np.cumsum(per_line) - per_line
    small = per_line < 3
    if small.any():
        warnings.append(f"{path.name}: {int(small.sum())} face(s) with fewer than 3 vertices ignored "
                        f"(first at line {int(f_lines[np.argmax(small)]) + 1})")
    keep = ~small
    return _Geometry(positions, colors, texcoords, normals, v_lines,
                     f_lines[keep], poly_start[keep], per_line[keep],
                     corner_v, corner_vt, corner_vn, dropped)


def _parse_faces(text: bytes, f_lines: np.ndarray, v_lines: np.ndarray, vt_lines: np.ndarray,
                 vn_lines: np.ndarray, lines: Lines, path: Path) -> tuple:
    """Parse a chunk of face lines (keywords blanked, every line ending in "\\n").

    Returns (corners per face (F,), corner v, vt, vn (C,) 0-based (-1 absent), the 0-based file
    line of each face (F,), the number of triangle faces dropped as degenerate). A triangle
    face naming one position twice (``f 1 1 2``) has no area whatever the coordinates, so it
    is dropped here, before anything is built for it.
    """
    if b"/" in text:
        text = text.replace(b"//", b"/" + _ABSENT_B + b"/")
        text = text.replace(b"/ ", b"/" + _ABSENT_B + b" ").replace(b"/\n", b"/" + _ABSENT_B + b"\n")
    arr = np.frombuffer(text, np.uint8)
    tok = token_layout(arr, f_lines.size)
    tok_starts, tok_line, per_line = tok.starts, tok.line, tok.per_line
    slash_pos = np.flatnonzero(arr == ord("/"))
    if slash_pos.size:
        tok_of_slash = np.searchsorted(tok_starts, slash_pos, side="right") - 1
        slashes = np.bincount(tok_of_slash, minlength=tok_starts.size)
    else:
        slashes = np.zeros(tok_starts.size, np.int64)
    ints = parse_ints(text.replace(b"/", b" ")) if slash_pos.size else parse_ints(text)
    if ints is None or (slashes > 2).any() or ints.size != int(tok_starts.size + slashes.sum()):
        _raise_bad_face(lines, path, f_lines)
    del arr, text
    comp_start = np.cumsum(slashes + 1) - (slashes + 1)
    raw_v = ints[comp_start]
    corner_face_line = f_lines[tok_line]  # 0-based file line of each corner
    corner_v = _resolve(raw_v, corner_face_line, v_lines, "vertex", path, optional=False)
    if slash_pos.size:
        raw_vt = np.where(slashes >= 1, ints[np.minimum(comp_start + 1, ints.size - 1)], _ABSENT)
        raw_vn = np.where(slashes == 2, ints[np.minimum(comp_start + 2, ints.size - 1)], _ABSENT)
        corner_vt = _resolve(raw_vt, corner_face_line, vt_lines, "texture coordinate", path, optional=True)
        corner_vn = _resolve(raw_vn, corner_face_line, vn_lines, "normal", path, optional=True)
    else:
        corner_vt = corner_vn = np.full(corner_v.size, -1, np.int64)
    # degenerate triangle faces: drop their lines and corners
    start = np.cumsum(per_line) - per_line
    tri = np.flatnonzero(per_line == 3)
    a, b, c = corner_v[start[tri]], corner_v[start[tri] + 1], corner_v[start[tri] + 2]
    bad = tri[(a == b) | (b == c) | (a == c)]
    if bad.size:
        keep_face = np.ones(per_line.size, bool)
        keep_face[bad] = False
        keep_corner = np.repeat(keep_face, per_line)
        return (per_line[keep_face], corner_v[keep_corner], corner_vt[keep_corner], corner_vn[keep_corner],
                f_lines[keep_face], int(bad.size))
    return per_line, corner_v, corner_vt, corner_vn, f_lines, 0


def _resolve(raw: np.ndarray, at_line: np.ndarray, defined_lines: np.ndarray, what: str,
             path: Path, optional: bool) -> np.ndarray:
    """OBJ indices (1-based, or negative = relative to what is defined so far) -> 0-based.

    raw (C,) int64 (``_ABSENT`` for a missing optional slot), at_line (C,) the 0-based line of
    each corner, defined_lines (N,) the sorted lines defining the N elements. Returns (C,)
    int64, -1 where absent. Raises InvalidGeometryError naming the first bad line.
    """
    total = defined_lines.size
    out = raw - 1
    negative = raw < 0
    if negative.any():
        before = np.searchsorted(defined_lines, at_line[negative])  # elements defined above the line
        out[negative] = before + raw[negative]
    absent = raw == _ABSENT
    bad = (out < 0) | (out >= total)
    bad &= ~absent
    if bad.any():
        k = int(np.argmax(bad))
        line, value = int(at_line[k]) + 1, int(raw[k])
        if value == 0:
            problem = f"face {what} index 0 is invalid (OBJ indices start at 1)"
        else:
            problem = f"face {what} index {value} is out of range ({total} defined)"
        raise InvalidGeometryError(path, f"line {line}: {problem}")
    if optional:
        out[absent] = -1
    return out


def _raise_bad_face(lines: Lines, path: Path, idx: np.ndarray) -> None:
    for i in idx:
        for tok in lines.text(int(i)).split("#", 1)[0].split()[1:]:
            parts = tok.split("/")
            try:
                if len(parts) > 3 or not parts[0]:
                    raise ValueError
                for part in parts:
                    if part:
                        int(part)
            except ValueError:
                raise AssetError(path, f"line {i + 1}: bad face vertex {tok[:40]!r} "
                                       "(expected v, v/vt, v//vn or v/vt/vn)") from None
    raise AssetError(path, "cannot read the face statements")


# --------------------------------------------------------------------------------------
# Triangulation and meshes


def _triangulate(geo: _Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Triangles as corner numbers: ((T, 3) int64 corners, (T,) polygon of each), file order."""
    per_poly = geo.poly_size - 2
    first_tri = np.cumsum(per_poly) - per_poly  # (P,) where each polygon's triangles go
    total = int(per_poly.sum())
    tris = np.empty((total, 3), np.int64)
    owner = np.repeat(np.arange(per_poly.size), per_poly)
    for n in np.unique(geo.poly_size):
        n = int(n)
        sel = np.flatnonzero(geo.poly_size == n) if n != geo.poly_size[0] or \
            not (geo.poly_size == n).all() else np.arange(per_poly.size)
        corners = geo.poly_start[sel][:, None] + np.arange(n)  # (Ps, n)
        if n == 3:
            tris[first_tri[sel]] = corners
        else:
            local = triangulate_polygons(geo.positions[geo.corner_v[corners]])  # (Ps, n-2, 3)
            where = (first_tri[sel][:, None] + np.arange(n - 2)).reshape(-1)
            tris[where] = np.take_along_axis(corners[:, None, :], local, axis=2).reshape(-1, 3)
    return tris, owner


def _drop_duplicate_triangles(geo: _Geometry, state: _State) -> tuple[_Geometry, int]:
    """Drop triangle faces repeating an earlier one exactly (same corners, same v/vt/vn, any
    rotation, same object/group/material). Returns (geometry, faces dropped).

    A repeated face adds nothing but work (2 million ``f 1 2 3`` lines once made the build run
    for minutes); a *reversed* repeat is kept: it is the back face of a two-sided surface.
    """
    tri = np.flatnonzero(geo.poly_size == 3)
    if tri.size < 2:
        return geo, 0
    event = np.searchsorted(np.asarray(state.event_lines), geo.poly_line[tri], side="right") - 1
    key = np.asarray(state.event_keys, np.int64)[event]
    c = geo.poly_start[tri][:, None] + np.arange(3)  # (T, 3) corner numbers
    # one integer per (v, vt, vn) corner; rotate each triangle so its smallest corner comes
    # first (the rotations of a triangle are the same triangle)
    nt, nn = geo.texcoords.shape[0] + 1, geo.normals.shape[0] + 1
    if geo.positions.shape[0] * nt * nn < (1 << 62):
        ids = (geo.corner_v[c] * nt + geo.corner_vt[c] + 1) * nn + geo.corner_vn[c] + 1  # (T, 3)
    else:
        triple = np.stack([geo.corner_v[c], geo.corner_vt[c], geo.corner_vn[c]], axis=2)  # (T, 3, 3)
        ids = unique_rows(triple.reshape(-1, 3))[1].reshape(-1, 3)
    first = np.argmin(ids, axis=1)
    rot = (first[:, None] + np.arange(3)) % 3
    canon = np.take_along_axis(ids, rot, axis=1)
    keep_idx = np.sort(unique_rows(np.concatenate([key[:, None], canon], axis=1))[0])
    if keep_idx.size == tri.size:
        return geo, 0
    keep_face = np.ones(geo.poly_size.size, bool)
    keep_face[tri] = False
    keep_face[tri[keep_idx]] = True
    keep_corner = np.repeat(keep_face, geo.poly_size)
    corner_pos = np.cumsum(keep_corner) - 1  # new corner number of every kept corner
    poly_start = corner_pos[geo.poly_start[keep_face]]
    out = _Geometry(geo.positions, geo.colors, geo.texcoords, geo.normals, geo.v_lines,
                    geo.poly_line[keep_face], poly_start, geo.poly_size[keep_face],
                    geo.corner_v[keep_corner], geo.corner_vt[keep_corner], geo.corner_vn[keep_corner],
                    geo.degenerate)
    return out, int(tri.size - keep_idx.size)


@dataclass
class _State:
    """The grouping statements seen so far (o, g, usemtl), as events by line."""

    event_lines: list[int] = field(default_factory=lambda: [-1])
    event_keys: list[int] = field(default_factory=lambda: [0])
    keys: dict[tuple[str | None, str | None, str | None], int] = field(
        default_factory=lambda: {(None, None, None): 0})
    obj: str | None = None
    group: str | None = None
    material: str | None = None

    def change(self, line: int, obj: str | None, group: str | None, material: str | None) -> None:
        self.obj, self.group, self.material = obj, group, material
        key = (obj, group, material)
        kid = self.keys.setdefault(key, len(self.keys))
        self.event_lines.append(line)
        self.event_keys.append(kid)


def _scan_statements(lines: Lines, path: Path, warnings: list[str]) -> tuple[_State, list[tuple[int, str]]]:
    """Read the non-numeric statements: grouping events and ``mtllib`` arguments."""
    state = _State()
    mtllibs: list[tuple[int, str]] = []
    skipped: dict[str, int] = {}
    unknown: dict[str, int] = {}
    for i in np.flatnonzero(lines.cls == OTHER):
        i = int(i)
        text = lines.text(i)
        keyword, _, rest = text.partition(" ")
        rest = rest.strip()
        if keyword == "o":
            state.change(i, rest or None, None, state.material)
        elif keyword == "g":
            state.change(i, state.obj, rest or None, state.material)
        elif keyword == "usemtl":
            state.change(i, state.obj, state.group, rest or None)
        elif keyword == "mtllib":
            if rest:
                mtllibs.append((i, rest))
        elif keyword in _IGNORED:
            pass
        elif keyword in ("l", "p") or keyword in _FREEFORM:
            skipped[keyword] = skipped.get(keyword, 0) + 1
        else:
            unknown[keyword[:20]] = unknown.get(keyword[:20], 0) + 1
    if skipped:
        what = ", ".join(f"{n} {k!r}" for k, n in skipped.items())
        warnings.append(f"{path.name}: ignored statements (lines, points, free-form geometry): {what}")
    if unknown:
        what = ", ".join(f"{n} {k!r}" for k, n in list(unknown.items())[:5])
        warnings.append(f"{path.name}: unknown statements ignored: {what}")
    return state, mtllibs


def _unique_vertices(keys: np.ndarray, key_range: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct values of ``keys`` (C,) in order of first use.

    keys (C,) int64 in [0, key_range). Returns (first use of each distinct value (N,) int64,
    inverse (C,) int64 in [0, N)). A lookup table is used when the key range is small
    (linear time), a sort otherwise.
    """
    count = keys.size
    if key_range <= 4 * count + (1 << 20):
        first_use = np.full(key_range, count, np.int64)
        np.minimum.at(first_use, keys, np.arange(count))
        used = np.flatnonzero(first_use < count)
        firsts = first_use[used]
        order = np.argsort(firsts)
        table = np.empty(key_range, np.int64)
        table[used[order]] = np.arange(used.size)
        return firsts[order], table[keys]
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return first[order], rank[inverse.reshape(-1)]


def _unit_normals(normals: np.ndarray, positions: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, int]:
    """Normalise (N, 3) normals; returns ((N, 3) float32 unit normals, how many were repaired).

    Zero-length normals (``vn 0 0 0`` happens in real files, e.g. spider.obj) are replaced by
    the area-weighted normal of the triangles using the vertex (positions (N, 3), indices
    (M, 3)), or +z when those triangles have no area.
    """
    length = np.linalg.norm(normals, axis=1)
    zero = ~(length > 0)
    out = normals / np.where(zero, 1.0, length)[:, None]
    if not zero.any():
        return out.astype(np.float32), 0
    p = positions[indices]  # (M, 3, 3)
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # (M, 3), length = 2 * area
    acc = np.zeros_like(out)
    for k in range(3):
        np.add.at(acc, indices[:, k], face)
    acc_len = np.linalg.norm(acc, axis=1)
    fixed = np.where(acc_len[:, None] > 0, acc / np.where(acc_len > 0, acc_len, 1.0)[:, None], [0.0, 0.0, 1.0])
    out[zero] = fixed[zero]
    return out.astype(np.float32), int(zero.sum())


def _build_meshes(geo: _Geometry, state: _State, material_index: dict[str, int], path: Path,
                  warnings: list[str]) -> list[MeshData]:
    corners, owner = _triangulate(geo)
    if corners.shape[0] == 0:
        return []
    event = np.searchsorted(np.asarray(state.event_lines), geo.poly_line, side="right") - 1
    poly_key = np.asarray(state.event_keys)[event]  # (P,) grouping key of each polygon
    tri_key = poly_key[owner]
    key_ids, first_tri, tri_count = np.unique(tri_key, return_index=True, return_counts=True)
    # triangles grouped by key, file order inside each group
    by_key = np.arange(tri_key.size) if key_ids.size == 1 else np.argsort(tri_key, kind="stable")
    key_offset = dict(zip(key_ids.tolist(), (np.cumsum(tri_count) - tri_count).tolist()))
    key_count = dict(zip(key_ids.tolist(), tri_count.tolist()))
    names = {kid: key for key, kid in state.keys.items()}

    # One integer per (v, vt, vn) triple; dense ids when the product would overflow int64.
    nv, nt, nn = geo.positions.shape[0], geo.texcoords.shape[0], geo.normals.shape[0]
    key_range = nv * (nt + 1) * (nn + 1)
    if key_range < (1 << 62):
        triple = (geo.corner_v * (nt + 1) + geo.corner_vt + 1) * (nn + 1) + geo.corner_vn + 1
    else:
        triple = np.unique(np.stack([geo.corner_v, geo.corner_vt, geo.corner_vn], 1),
                           axis=0, return_inverse=True)[1].reshape(-1)
        key_range = int(triple.max()) + 1

    unknown_materials: set[str] = set()
    meshes: list[MeshData] = []
    for kid in key_ids[np.argsort(first_tri, kind="stable")]:
        obj, group, mat_name = names[int(kid)]
        start = key_offset[int(kid)]
        tri_corners = corners[by_key[start:start + key_count[int(kid)]]]  # (M, 3) corner numbers
        first, inverse = _unique_vertices(triple[tri_corners.reshape(-1)], key_range)
        used = tri_corners.reshape(-1)[first]  # (N,) one corner standing for each output vertex
        name = group or obj or path.stem
        v, vt, vn = geo.corner_v[used], geo.corner_vt[used], geo.corner_vn[used]

        uv0 = None
        if (vt >= 0).any():
            uv = geo.texcoords[np.maximum(vt, 0)].copy()
            uv[:, 1] = 1.0 - uv[:, 1]
            if (vt < 0).any():
                uv[vt < 0] = 0.0
                warnings.append(f"{path.name}: mesh {name!r}: some faces have no texture coordinates (set to 0)")
            uv0 = uv.astype(np.float32)
        normals = None
        if (vn >= 0).all():
            normals, repaired = _unit_normals(geo.normals[vn], geo.positions[v], inverse.reshape(-1, 3))
            if repaired:
                warnings.append(f"{path.name}: mesh {name!r}: {repaired} zero-length normal(s) "
                                "replaced by the surrounding faces' normal")
        elif (vn >= 0).any():
            warnings.append(f"{path.name}: mesh {name!r}: some faces have no normals: normals dropped")

        material = -1
        if mat_name is not None:
            if mat_name in material_index:
                material = material_index[mat_name]
            elif mat_name not in unknown_materials:
                unknown_materials.add(mat_name)
                warnings.append(f"{path.name}: material {mat_name!r} is not defined in any material library: "
                                "using the default material")
        meshes.append(MeshData(
            name=name,
            positions=geo.positions[v],
            indices=inverse.reshape(-1, 3).astype(np.uint32),
            material=material,
            uv0=uv0,
            normals=normals,
            colors=None if geo.colors is None else geo.colors[v],
        ))
    return meshes


# --------------------------------------------------------------------------------------
# Entry point


def import_obj(path: Path, budgets: InputBudgets = DEFAULT_INPUT_BUDGETS) -> ImportedModel:
    """Import a Wavefront OBJ file with its MTL material libraries and their textures.

    Returns an :class:`ImportedModel` whose meshes have float64 (N, 3) positions, uint32
    (M, 3) indices, float32 (N, 2) ``uv0`` with v flipped (v' = 1 - v; None without ``vt``),
    float32 (N, 3) unit ``normals`` (None without ``vn``) and float32 (N, 4) ``colors`` when
    the file has vertex colours. Raises :class:`AssetError` subclasses for bad input, and
    for a file over ``budgets`` (triangles, coordinates: see :mod:`pipelines.budgets`).
    Degenerate triangle faces (a vertex named twice) and exact repeats of a triangle face are
    dropped, with a warning, before anything is built for them.
    """
    path = Path(path)
    ctx = ObjContext(path=path, finder=Finder(path.parent))
    data = read_normalised(path, "OBJ", ctx.warnings)
    lines = Lines.split(data)
    del data
    geo = _parse_geometry(lines, path, ctx.warnings, budgets)
    state, mtllibs = _scan_statements(lines, path, ctx.warnings)
    if geo.poly_size.size == 0:
        if geo.degenerate:
            raise InvalidGeometryError(path, f"all its {geo.degenerate} faces are degenerate (a vertex named twice): "
                                             "nothing to build")
        raise AssetError(path, "contains no faces (is this an OBJ file?)")
    geo, repeated = _drop_duplicate_triangles(geo, state)
    if repeated:
        ctx.warnings.append(f"{path.name}: {repeated} repeated triangle face(s) ignored (same corners as an earlier face)")
    triangles = int((geo.poly_size - 2).sum())
    if triangles > budgets.max_triangles:
        raise AssetError(path, f"has {triangles} triangles after triangulation: over the triangle budget of "
                               f"{budgets.max_triangles}")
    materials, index = load_materials(mtllibs, ctx)
    meshes = _build_meshes(geo, state, index, path, ctx.warnings)
    return ImportedModel(
        source=path,
        meshes=tuple(meshes),
        materials=tuple(materials),
        warnings=tuple(ctx.warnings),
        dependencies=tuple(ctx.dependencies),
    )
