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
* ``mtllib`` (several files, names with spaces), materials: see :func:`_build_material`.
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

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assetpipe.core.errors import AssetError, InvalidGeometryError, MissingFileError
from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, InputBudgets
from assetpipe.pipelines.image_source import read_image_file, resolve_inside
from assetpipe.pipelines.model import (
    CLAMP_TO_EDGE,
    ImageSource,
    ImportedModel,
    Material,
    MeshData,
    Sampler,
    TextureRef,
)
from assetpipe.pipelines.triangulate import triangulate_polygons

__all__ = ["import_obj"]

# Line classes.
_BLANK, _COMMENT, _V, _VT, _VN, _F, _OTHER = range(7)
_SPACE, _NL = 32, 10
# Stands for an absent vt/vn slot ("1//3", "1/2/") while parsing: never a real index.
_ABSENT = 1 << 62
_ABSENT_B = str(_ABSENT).encode()
# Files searched at most when looking a texture up by name under the model's folder.
_MAX_INDEXED_FILES = 50_000
# Face lines parsed at a time (bounds the parsing temporaries: about 100 bytes per face line).
_FACE_CHUNK_LINES = 1 << 20

_FREEFORM = frozenset({"vp", "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm",
                       "trim", "hole", "scrv", "sp", "end", "con"})
_IGNORED = frozenset({"s", "mg", "usemap", "maplib", "shadow_obj", "trace_obj", "bevel",
                      "c_interp", "d_interp", "lod", "ctech", "stech", "call", "csh"})

# Options of MTL map statements and how many arguments they take (max; -o/-s/-t take 1..3).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1,
                "-colorspace": 1}
_NUMERIC_OPTIONS = frozenset({"-bm", "-boost", "-mm", "-o", "-s", "-t", "-texres"})
_FLOAT_RE = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


# --------------------------------------------------------------------------------------
# Reading text files


def _read_normalised(path: Path, what: str, warnings: list[str] | None = None) -> bytes:
    """Read a text file and return it as bytes with ``\\n`` line ends, ending in ``\\n``.

    UTF-8 (BOM stripped) stays as it is, UTF-16 with a BOM is re-encoded as UTF-8; tabs and
    other blanks become spaces; ``\\`` continuations are joined, followed by as many empty
    lines as were joined, so line numbers still match the file. A few lines holding binary
    bytes (NUL and other control characters) are blanked with a warning naming them (as
    tinyobjloader and Assimp skip a bad line); a file that is mostly such lines is refused as
    binary (see :func:`_skip_binary_lines`).
    """
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise MissingFileError(path, f"{what} file not found") from None
    except OSError as err:
        raise AssetError(path, f"cannot read the {what} file: {err.strerror or err}") from None
    if raw.startswith(b"version https://git-lfs"):
        raise AssetError(path, f"is a Git LFS pointer, not the {what} file itself (run git lfs pull)")
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    elif raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            raw = raw.decode("utf-16").encode("utf-8")
        except UnicodeDecodeError:
            raise AssetError(path, f"is not valid UTF-16 text (it starts with a UTF-16 byte-order mark)") from None
    data = raw
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if len(data.translate(None, _BINARY_BYTES)) != len(data):
        data = _skip_binary_lines(data, path, what, warnings)
    if b"\t" in data or b"\v" in data or b"\f" in data:
        data = data.translate(_BLANKS)
    if not data.endswith(b"\n"):
        data += b"\n"
    if b"\\\n" in data:
        data = _join_continuations(data)
    return data


_BLANKS = bytes.maketrans(b"\t\v\f", b"   ")
_MAX_BINARY_LINES = 16


# control bytes no text file holds (C0 controls but tab, newline, vertical tab, form feed, CR)
_BINARY_BYTES = bytes(b for b in range(32) if b not in (9, 10, 11, 12, 13)) + b"\x7f"


def _skip_binary_lines(data: bytes, path: Path, what: str, warnings: list[str] | None) -> bytes:
    """Blank the lines of ``data`` that hold control bytes, or refuse the file as binary: when
    they are more than ``_MAX_BINARY_LINES`` lines and 1% of the lines, half of the lines, or
    10% of the bytes."""
    buf = np.frombuffer(data, np.uint8)
    binary = np.zeros(256, bool)
    binary[np.frombuffer(_BINARY_BYTES, np.uint8)] = True
    junk = np.flatnonzero(binary[buf])
    nl = np.flatnonzero(buf == _NL)
    total_lines = nl.size + (0 if data.endswith(b"\n") else 1)
    bad = np.unique(np.searchsorted(nl, junk))  # line of each control byte (newlines before it)
    refuse = (junk.size * 10 > buf.size or bad.size * 2 >= total_lines
              or (bad.size > _MAX_BINARY_LINES and bad.size * 100 > total_lines))
    if refuse or warnings is None:
        raise AssetError(path, f"is a binary file, not a text {what} file (or UTF-16 without a byte-order mark)")
    out = buf.copy()
    for line in bad.tolist():
        start = int(nl[line - 1]) + 1 if line else 0
        end = int(nl[line]) if line < nl.size else out.size
        out[start:end] = _SPACE
    shown = ", ".join(str(line + 1) for line in bad[:5].tolist()) + (", ..." if bad.size > 5 else "")
    warnings.append(f"{path.name}: {bad.size} line(s) with binary bytes skipped (line {shown})")
    return out.tobytes()


def _join_continuations(data: bytes) -> bytes:
    """Join lines ending in a backslash with the next one, keeping the line count."""
    out: list[bytes] = []
    pending: list[bytes] = []
    for line in data.split(b"\n"):
        if line.endswith(b"\\"):
            pending.append(line[:-1])
            continue
        if pending:
            out.append(b" ".join(pending + [line]))
            out.extend([b""] * len(pending))
            pending = []
        else:
            out.append(line)
    if pending:
        out.append(b" ".join(pending))
        out.extend([b""] * (len(pending) - 1))
    return b"\n".join(out)


def _decode(b: bytes) -> str:
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("latin-1")


# --------------------------------------------------------------------------------------
# Vectorised line classification and number parsing


@dataclass
class _Lines:
    """The lines of a normalised file. All arrays have one entry per line (L lines)."""

    data: bytes
    starts: np.ndarray  # (L,) int64 offset of the line's first byte
    ends: np.ndarray  # (L,) int64 offset of its "\n"
    first: np.ndarray  # (L,) int64 offset of its first non-blank byte (== end if blank)
    cls: np.ndarray  # (L,) int8 line class (_V, _F, ...)
    _byte_cls: np.ndarray | None = None  # (B,) int8 class of every byte, built on first use

    @classmethod
    def split(cls, data: bytes) -> "_Lines":
        buf = np.frombuffer(data, np.uint8)
        ends = np.flatnonzero(buf == _NL)
        starts = np.empty_like(ends)
        starts[0] = 0
        starts[1:] = ends[:-1] + 1
        first = starts.copy()
        indented = np.flatnonzero(buf[starts] == _SPACE)
        if indented.size:  # rare: only these lines need a search for their first non-blank
            nonblank = np.flatnonzero(buf != _SPACE)  # includes the "\n"s, so always found
            first[indented] = nonblank[np.searchsorted(nonblank, starts[indented])]
        pad = np.frombuffer(data + b"   ", np.uint8)
        c0, c1, c2 = pad[first], pad[first + 1], pad[first + 2]
        sep1 = (c1 == _SPACE) | (c1 == _NL)
        sep2 = (c2 == _SPACE) | (c2 == _NL)
        kind = np.full(ends.shape, _OTHER, np.int8)
        kind[c0 == ord("#")] = _COMMENT
        is_v = c0 == ord("v")
        kind[is_v & sep1] = _V
        kind[is_v & (c1 == ord("t")) & sep2] = _VT
        kind[is_v & (c1 == ord("n")) & sep2] = _VN
        kind[(c0 == ord("f")) & sep1] = _F
        kind[first == ends] = _BLANK
        return cls(data, starts, ends, first, kind)

    def text(self, i: int) -> str:
        return _decode(self.data[self.starts[i]:self.ends[i]]).strip()

    def region(self, kind: int, keyword_len: int) -> tuple[bytes, np.ndarray]:
        """The bytes of all lines of one class, keywords blanked, each line ending in "\\n".

        Returns (bytes, line numbers (K,) int64, 0-based, of those lines). ``#`` comments at
        the end of the lines are blanked too.
        """
        idx = np.flatnonzero(self.cls == kind)
        buf = np.frombuffer(self.data, np.uint8)
        lengths = self.ends - self.starts + 1
        if self._byte_cls is None:
            self._byte_cls = np.repeat(self.cls, lengths)
        mask = self._byte_cls == kind
        # keyword bytes, relative positions inside the kept bytes
        out = buf[mask]
        kept_starts = np.cumsum(lengths[idx]) - lengths[idx]
        kw = kept_starts + (self.first[idx] - self.starts[idx])
        for k in range(keyword_len):
            out[kw + k] = _SPACE
        if b"#" in self.data:
            _blank_comments(out)
        return out.tobytes(), idx


def _blank_comments(arr: np.ndarray) -> None:
    """In place: blank every byte from a "#" to the end of its line (arr (B,) uint8)."""
    hashes = np.flatnonzero(arr == ord("#"))
    if hashes.size == 0:
        return
    newline = arr == _NL
    line_of = np.cumsum(newline) - newline
    first_hash = np.full(int(line_of[-1]) + 1, arr.size, np.int64)
    np.minimum.at(first_hash, line_of[hashes], hashes)
    kill = (np.arange(arr.size) >= first_hash[line_of]) & ~newline
    arr[kill] = _SPACE


@dataclass
class _Tokens:
    """Whitespace-separated tokens of a region (bytes, every line ending in "\\n")."""

    starts: np.ndarray  # (T,) int64 offset of each token's first byte
    ends: np.ndarray  # (T,) int64 offset just past each token
    line: np.ndarray  # (T,) int64 region line (0..K-1) of each token
    per_line: np.ndarray  # (K,) int64 tokens on each line


def _token_layout(arr: np.ndarray, n_lines: int) -> _Tokens:
    """Token boundaries of a region: arr (B,) uint8 holding n_lines lines."""
    if arr.size == 0:
        empty = np.zeros(0, np.int64)
        return _Tokens(empty, empty, empty, np.zeros(n_lines, np.int64))
    newline = arr == _NL
    blank = (arr == _SPACE) | newline
    edge = np.diff(blank.view(np.int8), prepend=np.int8(1), append=np.int8(1))
    starts = np.flatnonzero(edge == -1)  # blank -> non-blank
    ends = np.flatnonzero(edge == 1)  # non-blank -> blank
    nl_pos = np.flatnonzero(newline)
    tok_line = np.searchsorted(nl_pos, starts)  # newlines before the token
    return _Tokens(starts, ends, tok_line, np.bincount(tok_line, minlength=n_lines))


_DOT_MINUS_TO_BLANK = bytes.maketrans(b".-", b"  ")
_POW10 = 10.0 ** np.arange(19)
_IPOW10 = 10 ** np.arange(19, dtype=np.int64)


def _fast_decimals(text: bytes, arr: np.ndarray, tok: _Tokens) -> np.ndarray | None:
    """Parse tokens of the plain form ``-?digits.digits`` exactly like strtod, vectorised.

    Each number is read as an integer mantissa m and a count d of decimals and computed as
    m / 10**d, which is correctly rounded (the same double as strtod) when m < 2**53 and
    d <= 18: both are exact doubles and IEEE division rounds once. Returns (T,) float64, or
    None when any token has another form (exponent, no dot, nan, ...) or too many digits: the
    caller then uses the general parser.
    """
    count = tok.starts.size
    if count == 0 or text.translate(None, b"0123456789.- \n"):
        return None  # some byte other than digits, ".", "-" and blanks
    dots = np.flatnonzero(arr == ord("."))
    if dots.size != count:
        return None
    negative = arr[tok.starts] == ord("-")
    int_start = tok.starts + negative
    decimals = tok.ends - dots - 1
    if ((dots <= int_start) | (decimals < 1) | (decimals > 18) | (dots >= tok.ends)).any():
        return None  # also catches a dot outside its token: dots and tokens pair up one to one
    minus = np.flatnonzero(arr == ord("-"))
    if minus.size != int(negative.sum()):
        return None  # a "-" elsewhere than at the start of a token
    try:
        ints = np.fromstring(text.translate(_DOT_MINUS_TO_BLANK), dtype=np.int64, sep=" ")
    except ValueError:
        return None
    if ints.size != 2 * count:
        return None
    whole, frac = ints[0::2], ints[1::2]
    if (whole >= (1 << 53)).any():
        return None
    mantissa = whole * _IPOW10[decimals] + frac  # may wrap for huge values: checked below
    if ((mantissa >= (1 << 53)) | (mantissa < 0) | (whole > (1 << 53) // _IPOW10[decimals])).any():
        return None
    values = mantissa / _POW10[decimals]
    values[negative] *= -1.0
    return values


def _parse_floats(text: bytes) -> np.ndarray | None:
    """All numbers of a whitespace-separated byte string as float64, or None if one is bad."""
    if not text.strip():
        return np.zeros(0, np.float64)
    try:
        return np.fromstring(text, dtype=np.float64, sep=" ")
    except ValueError:
        return None


def _parse_ints(text: bytes) -> np.ndarray | None:
    if not text.strip():
        return np.zeros(0, np.int64)
    try:
        return np.fromstring(text, dtype=np.int64, sep=" ")
    except ValueError:
        return None


def _ragged_to_matrix(values: np.ndarray, counts: np.ndarray, width: int, fill: float) -> np.ndarray:
    """Rows of ``counts[i]`` values each -> (L, width) float64, cut or padded with ``fill``."""
    rows = counts.shape[0]
    if rows and (counts == width).all():
        return values.reshape(rows, width)
    out = np.full((rows, width), fill, np.float64)
    take = np.minimum(counts, width)
    row = np.repeat(np.arange(rows), take)
    col = np.arange(int(take.sum())) - np.repeat(np.cumsum(take) - take, take)
    src = np.repeat(np.cumsum(counts) - counts, take) + col
    out[row, col] = values[src]
    return out


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


def _numeric_lines(lines: _Lines, path: Path, kind: int, keyword: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(values (K*?,) float64, counts per line (K,), line numbers (K,)) of one statement kind."""
    text, idx = lines.region(kind, len(keyword))
    arr = np.frombuffer(text, np.uint8)
    tok = _token_layout(arr, idx.size)
    counts = tok.per_line
    values = _fast_decimals(text, arr, tok)
    if values is None:
        values = _parse_floats(text)
    if values is None or values.size != int(counts.sum()):
        _raise_bad_number(lines, path, idx, keyword)
    return values, counts, idx


def _raise_bad_number(lines: _Lines, path: Path, idx: np.ndarray, keyword: str) -> None:
    for i in idx:
        tokens = lines.text(int(i)).split("#", 1)[0].split()[1:]
        for tok in tokens:
            try:
                float(tok)
            except ValueError:
                raise AssetError(path, f"line {i + 1}: {keyword!r} statement has a bad number {tok[:40]!r}") from None
    raise AssetError(path, f"cannot read the {keyword!r} statements")  # not reached in practice


def _parse_geometry(lines: _Lines, path: Path, warnings: list[str],
                    budgets: InputBudgets = DEFAULT_INPUT_BUDGETS) -> _Geometry:
    # -- v
    values, counts, v_lines = _numeric_lines(lines, path, _V, "v")
    if (counts < 3).any():
        bad = int(v_lines[np.argmax(counts < 3)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a vertex needs 3 coordinates")
    vmat = _ragged_to_matrix(values, counts, 7, np.nan)
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
    values, counts, vt_lines = _numeric_lines(lines, path, _VT, "vt")
    if (counts < 1).any():
        bad = int(vt_lines[np.argmax(counts < 1)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a texture coordinate needs a value")
    texcoords = _ragged_to_matrix(values, counts, 2, 0.0)
    ok = np.isfinite(texcoords).all(axis=1)
    if not ok.all():
        k = int(np.argmin(ok))
        raise InvalidGeometryError(path, f"texture coordinate {k + 1} (line {vt_lines[k] + 1}) is not finite")
    # -- vn
    values, counts, vn_lines = _numeric_lines(lines, path, _VN, "vn")
    if (counts < 3).any():
        bad = int(vn_lines[np.argmax(counts < 3)])
        raise InvalidGeometryError(path, f"line {bad + 1}: a normal needs 3 coordinates")
    normals = np.ascontiguousarray(_ragged_to_matrix(values, counts, 3, 0.0))
    ok = np.isfinite(normals).all(axis=1)
    if not ok.all():
        k = int(np.argmin(ok))
        raise InvalidGeometryError(path, f"normal {k + 1} (line {vn_lines[k] + 1}) is not finite")

    # -- f, in chunks of lines so the parsing temporaries stay bounded (a 80 MB file of 10M
    # "f 1 1 1" lines took 3.75 GB parsed whole); degenerate triangles are dropped per chunk.
    text, f_lines = lines.region(_F, 1)
    arr = np.frombuffer(text, np.uint8)
    nl = np.flatnonzero(arr == _NL)
    parts: list[tuple[np.ndarray, ...]] = []
    dropped = 0
    for c0 in range(0, f_lines.size, _FACE_CHUNK_LINES):
        c1 = min(c0 + _FACE_CHUNK_LINES, f_lines.size)
        b0 = int(nl[c0 - 1]) + 1 if c0 else 0
        b1 = int(nl[c1 - 1]) + 1
        part = _parse_faces(text[b0:b1], f_lines[c0:c1], v_lines, vt_lines, vn_lines, lines, path)
        dropped += part[-1]
        parts.append(part[:-1])
    del arr, nl, text
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
                 vn_lines: np.ndarray, lines: _Lines, path: Path) -> tuple:
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
    tok = _token_layout(arr, f_lines.size)
    tok_starts, tok_line, per_line = tok.starts, tok.line, tok.per_line
    slash_pos = np.flatnonzero(arr == ord("/"))
    if slash_pos.size:
        tok_of_slash = np.searchsorted(tok_starts, slash_pos, side="right") - 1
        slashes = np.bincount(tok_of_slash, minlength=tok_starts.size)
    else:
        slashes = np.zeros(tok_starts.size, np.int64)
    ints = _parse_ints(text.replace(b"/", b" ")) if slash_pos.size else _parse_ints(text)
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


def _raise_bad_face(lines: _Lines, path: Path, idx: np.ndarray) -> None:
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


def _first_unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index of the first occurrence of each distinct row, row id of every row) of (R, k) int64
    rows, by one lexsort (np.unique(axis=0) was 10x slower here)."""
    order = np.lexsort(rows.T[::-1])
    sorted_rows = rows[order]
    new = np.ones(rows.shape[0], bool)
    new[1:] = (sorted_rows[1:] != sorted_rows[:-1]).any(axis=1)
    group = np.cumsum(new) - 1
    ids = np.empty(rows.shape[0], np.int64)
    ids[order] = group
    firsts = np.full(int(group[-1]) + 1 if rows.shape[0] else 0, rows.shape[0], np.int64)
    np.minimum.at(firsts, group, order)
    return firsts, ids


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
        ids = _first_unique_rows(triple.reshape(-1, 3))[1].reshape(-1, 3)
    first = np.argmin(ids, axis=1)
    rot = (first[:, None] + np.arange(3)) % 3
    canon = np.take_along_axis(ids, rot, axis=1)
    keep_idx = np.sort(_first_unique_rows(np.concatenate([key[:, None], canon], axis=1))[0])
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


def _scan_statements(lines: _Lines, path: Path, warnings: list[str]) -> tuple[_State, list[tuple[int, str]]]:
    """Read the non-numeric statements: grouping events and ``mtllib`` arguments."""
    state = _State()
    mtllibs: list[tuple[int, str]] = []
    skipped: dict[str, int] = {}
    unknown: dict[str, int] = {}
    for i in np.flatnonzero(lines.cls == _OTHER):
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
# Finding files inside the model's folder


class _Finder:
    """Looks referenced files (MTL, textures) up inside the model's folder only."""

    def __init__(self, root: Path):
        self.root = root.resolve()
        self._index: dict[str, list[Path]] | None = None
        self._index_lower: dict[str, list[Path]] | None = None

    def _build_index(self) -> None:
        exact: dict[str, list[Path]] = {}
        lower: dict[str, list[Path]] = {}
        count = 0
        for dirpath, dirnames, filenames in os.walk(self.root):  # does not follow symlinked dirs
            dirnames.sort()
            for fname in sorted(filenames):
                p = Path(dirpath) / fname
                exact.setdefault(fname, []).append(p)
                lower.setdefault(fname.lower(), []).append(p)
                count += 1
            if count > _MAX_INDEXED_FILES:
                break
        key = lambda p: (len(p.parts), str(p))  # noqa: E731 - shallowest first, then by name
        self._index = {k: sorted(v, key=key) for k, v in exact.items()}
        self._index_lower = {k: sorted(v, key=key) for k, v in lower.items()}

    def find(self, written: str, rel_dirs: list[Path], referrer: Path, what: str) -> tuple[Path | None, str | None]:
        """Resolve a path as written in ``referrer``.

        Returns (the file, or None; a warning or None).
        """
        cleaned = written.strip().strip('"').replace("\\", "/")
        absolute = cleaned.startswith("/") or re.match(r"^[A-Za-z]:", cleaned) is not None
        escaped = False
        if cleaned and not absolute:
            for d in rel_dirs:
                rel = os.path.join(os.path.relpath(d, self.root), cleaned)
                try:
                    target = resolve_inside(self.root, rel, referrer)
                except AssetError:
                    escaped = True
                    continue
                if target.is_file():
                    return target, None
        name = cleaned.rstrip("/").rsplit("/", 1)[-1]
        found = self._by_name(name, referrer) if name not in ("", ".", "..") else None
        if found is not None:
            if escaped:
                return found, (f"{referrer.name}: {what} {written!r} points outside the model's folder; "
                               f"using {os.path.relpath(found, self.root)!r} found inside it")
            return found, None
        if escaped:
            return None, f"{referrer.name}: {what} {written!r} is outside the model's folder: not read"
        return None, f"{referrer.name}: {what} {written!r} not found"

    def _by_name(self, name: str, referrer: Path) -> Path | None:
        if self._index is None:
            self._build_index()
        assert self._index is not None and self._index_lower is not None
        for candidates in (self._index.get(name, []), self._index_lower.get(name.lower(), [])):
            for p in candidates:
                try:
                    target = resolve_inside(self.root, os.path.relpath(p, self.root), referrer)
                except AssetError:
                    continue  # a symlink leading out of the folder
                if target.is_file():
                    return target
        return None


# --------------------------------------------------------------------------------------
# MTL


@dataclass
class _MapRef:
    """A map statement: the file name as written and its options."""

    file: str
    clamp: bool = False
    transformed: bool = False  # -o / -s with non-default values


def _parse_map(rest: str) -> _MapRef | None:
    """Parse the arguments of a ``map_*`` / ``bump`` / ``norm`` statement (options, then file).

    The file name is the rest of the line after the options, spaces included.
    """
    spans = [(m.group(), m.start()) for m in re.finditer(r"\S+", rest)]
    i, clamp, transformed = 0, False, False
    while i < len(spans) - 1 and spans[i][0].startswith("-") and not _FLOAT_RE.match(spans[i][0]):
        opt = spans[i][0].lower()
        i += 1
        args: list[str] = []
        limit = _MAP_OPTIONS.get(opt, 3)
        numeric = opt in _NUMERIC_OPTIONS or opt not in _MAP_OPTIONS
        while len(args) < limit and i < len(spans) - 1:
            tok = spans[i][0]
            if numeric and not _FLOAT_RE.match(tok):
                break
            args.append(tok)
            i += 1
            if not numeric:
                break
        if opt == "-clamp" and args and args[0].lower() == "on":
            clamp = True
        if opt in ("-o", "-s"):
            default = 0.0 if opt == "-o" else 1.0
            if any(float(a) != default for a in args):
                transformed = True
    if i >= len(spans):
        return None
    return _MapRef(rest[spans[i][1]:].strip(), clamp, transformed)


def _floats(rest: str, count: int) -> tuple[float, ...] | None:
    try:
        vals = tuple(float(t) for t in rest.split()[:count])
    except ValueError:
        return None
    if len(vals) == 1 and count == 3:
        vals = vals * 3  # "Kd 0.5" means grey
    if len(vals) != count or not all(np.isfinite(vals)):
        return None
    return vals


def _parse_mtl(data: bytes, mtl_path: Path, warnings: list[str]) -> list[tuple[str, dict[str, object]]]:
    """The materials of an MTL file: [(name, {statement: parsed value})] in file order."""
    materials: list[tuple[str, dict[str, object]]] = []
    current: dict[str, object] | None = None
    for lineno, raw_line in enumerate(data.split(b"\n"), 1):
        text = _decode(raw_line).strip()
        if not text or text.startswith("#"):
            continue
        keyword, _, rest = text.partition(" ")
        keyword, rest = keyword.lower(), rest.strip()
        if keyword == "newmtl":
            current = {}
            materials.append((rest or "unnamed", current))
            continue
        if current is None:
            continue
        if keyword in ("kd", "ke"):
            vals = _floats(rest, 3)
            if vals is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: cannot read {keyword.capitalize()} {rest!r}")
            else:
                current[keyword] = vals
        elif keyword in ("d", "tr", "pm", "pr"):
            tokens = [t for t in rest.split() if t != "-halo"]
            vals = _floats(tokens[0] if tokens else "", 1)
            if vals is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: cannot read {keyword} {rest!r}")
            else:
                current[keyword] = vals[0]
        elif keyword in ("map_kd", "map_d", "map_bump", "bump", "norm", "map_ke", "map_kn"):
            ref = _parse_map(rest)
            if ref is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: {keyword} without a file name")
            else:
                role = {"map_bump": "bump", "norm": "bump", "map_kn": "bump"}.get(keyword, keyword)
                current.setdefault(role, ref)
    return materials


@dataclass
class _Context:
    """What an import accumulates: warnings, files read, images by path."""

    path: Path
    finder: _Finder
    warnings: list[str] = field(default_factory=list)
    dependencies: list[Path] = field(default_factory=list)
    images: dict[Path, ImageSource] = field(default_factory=dict)

    def read_dep(self, p: Path) -> None:
        if p not in self.dependencies:
            self.dependencies.append(p)

    def texture(self, ref: _MapRef, mtl_path: Path, what: str) -> TextureRef | None:
        found, warning = self.finder.find(ref.file, [mtl_path.parent, self.path.parent], mtl_path, what)
        if warning:
            self.warnings.append(warning)
        if found is None:
            return None
        image = self.images.get(found)
        if image is None:
            image = read_image_file(found, mtl_path, name=found.name)
            self.images[found] = image
            self.read_dep(found)
        if ref.transformed:
            self.warnings.append(f"{mtl_path.name}: texture options -o/-s on {ref.file!r} are not supported: ignored")
        sampler = Sampler(wrap_s=CLAMP_TO_EDGE, wrap_t=CLAMP_TO_EDGE) if ref.clamp else Sampler()
        return TextureRef(image=image, sampler=sampler)


def _build_material(name: str, st: dict[str, object], mtl_path: Path, ctx: _Context) -> Material:
    """One glTF-style material from MTL statements.

    * ``Kd`` -> base colour RGB (white if absent). A ``Kd 0 0 0`` next to a ``map_Kd`` would
      render the texture black (an exporter habit), so it becomes white, with a warning.
    * ``d`` -> alpha; without ``d``, ``Tr`` -> alpha = 1 - Tr. ``Tr 1`` alone (alpha 0, an
      invisible material) is what MeshLab and others write for *opaque*: read as alpha 1,
      with a warning. alpha < 1 -> alphaMode BLEND.
    * ``map_Kd`` -> base colour texture; ``map_Bump`` / ``bump`` / ``norm`` -> normal
      texture; ``Ke`` / ``map_Ke`` -> emissive; ``Pm`` / ``Pr`` -> metallic / roughness
      (metallic is 0 otherwise: OBJ materials are not metals).
    * ``map_d``: the model has no separate alpha texture. When it names the same image as
      ``map_Kd`` the texture's own alpha is meant: alphaMode BLEND. Otherwise it is ignored
      (never used as the base colour, since it is a grey mask) with a warning.
    """
    kd = st.get("kd", (1.0, 1.0, 1.0))
    assert isinstance(kd, tuple)
    alpha = 1.0
    if "d" in st:
        alpha = float(st["d"])  # type: ignore[arg-type]
    elif "tr" in st:
        alpha = 1.0 - float(st["tr"])  # type: ignore[arg-type]
        if alpha <= 0.0:
            ctx.warnings.append(f"{mtl_path.name}: material {name!r} has Tr {st['tr']} (fully transparent); "
                                "read as opaque, as the exporter most likely meant")
            alpha = 1.0
    alpha = min(max(alpha, 0.0), 1.0)
    alpha_mode = "BLEND" if alpha < 1.0 else "OPAQUE"

    base_tex = normal_tex = emissive_tex = None
    kd_ref = st.get("map_kd")
    if isinstance(kd_ref, _MapRef):
        base_tex = ctx.texture(kd_ref, mtl_path, "texture")
        if base_tex is not None and tuple(kd) == (0.0, 0.0, 0.0):
            ctx.warnings.append(f"{mtl_path.name}: material {name!r} has Kd 0 0 0 with a texture: "
                                "using white so the texture shows")
            kd = (1.0, 1.0, 1.0)
    d_ref = st.get("map_d")
    if isinstance(d_ref, _MapRef):
        same = isinstance(kd_ref, _MapRef) and base_tex is not None and \
            ctx.finder.find(d_ref.file, [mtl_path.parent, ctx.path.parent], mtl_path, "alpha texture")[0] \
            == Path(base_tex.image.origin)
        if same:
            alpha_mode = "BLEND"
        else:
            ctx.warnings.append(f"{mtl_path.name}: material {name!r}: separate alpha map {d_ref.file!r} "
                                "(map_d) is not supported: ignored")
    bump_ref = st.get("bump")
    if isinstance(bump_ref, _MapRef):
        normal_tex = ctx.texture(bump_ref, mtl_path, "normal texture")
    ke_ref = st.get("map_ke")
    if isinstance(ke_ref, _MapRef):
        emissive_tex = ctx.texture(ke_ref, mtl_path, "emissive texture")
    ke = st.get("ke", (1.0, 1.0, 1.0) if emissive_tex is not None else (0.0, 0.0, 0.0))
    assert isinstance(ke, tuple)
    return Material(
        name=name,
        base_color_factor=(float(kd[0]), float(kd[1]), float(kd[2]), alpha),
        base_color_texture=base_tex,
        alpha_mode=alpha_mode,
        metallic_factor=float(st.get("pm", 0.0)),  # type: ignore[arg-type]
        roughness_factor=float(st.get("pr", 1.0)),  # type: ignore[arg-type]
        normal_texture=normal_tex,
        emissive_texture=emissive_tex,
        emissive_factor=(float(ke[0]), float(ke[1]), float(ke[2])),
    )


def _split_mtllib(rest: str, finder: _Finder, ctx: _Context) -> list[str]:
    """The file names of an ``mtllib`` statement: several names, each possibly with spaces.

    The whole argument is one name if such a file exists; otherwise the words are grouped
    into names ending in ``.mtl``.
    """
    whole, _ = finder.find(rest, [ctx.path.parent], ctx.path, "material library")
    if whole is not None or " " not in rest:
        return [rest]
    names, current = [], []
    for word in rest.split():
        current.append(word)
        if word.lower().endswith(".mtl"):
            names.append(" ".join(current))
            current = []
    if current:
        names.append(" ".join(current))
    return names


def _load_materials(mtllibs: list[tuple[int, str]], ctx: _Context) -> tuple[list[Material], dict[str, int]]:
    materials: list[Material] = []
    index: dict[str, int] = {}
    seen: set[Path] = set()
    for _, rest in mtllibs:
        for name in _split_mtllib(rest, ctx.finder, ctx):
            found, warning = ctx.finder.find(name, [ctx.path.parent], ctx.path, "material library")
            if found is None:
                ctx.warnings.append((warning or f"material library {name!r} not found") +
                                    ": its materials use the default material")
                continue
            if found in seen:
                continue
            seen.add(found)
            if warning:
                ctx.warnings.append(warning)
            data = _read_normalised(found, "MTL", ctx.warnings)
            ctx.read_dep(found)
            for mat_name, statements in _parse_mtl(data, found, ctx.warnings):
                if mat_name in index:
                    ctx.warnings.append(f"{found.name}: material {mat_name!r} defined again: the first one is used")
                    continue
                index[mat_name] = len(materials)
                materials.append(_build_material(mat_name, statements, found, ctx))
    return materials, index


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
    ctx = _Context(path=path, finder=_Finder(path.parent))
    data = _read_normalised(path, "OBJ", ctx.warnings)
    lines = _Lines.split(data)
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
    materials, index = _load_materials(mtllibs, ctx)
    meshes = _build_meshes(geo, state, index, path, ctx.warnings)
    return ImportedModel(
        source=path,
        meshes=tuple(meshes),
        materials=tuple(materials),
        warnings=tuple(ctx.warnings),
        dependencies=tuple(ctx.dependencies),
    )
