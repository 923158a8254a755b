"""Reading OBJ and MTL text: normalised bytes, and vectorised line classification and number
parsing (no Python loop over the v/vt/vn/f lines). Used by :mod:`pipelines.import_obj` and
:mod:`pipelines.obj_mtl`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from assetpipe.core.errors import AssetError, MissingFileError

# Line classes.
BLANK, COMMENT, V, VT, VN, F, OTHER = range(7)
SPACE, NL = 32, 10


# --------------------------------------------------------------------------------------
# Reading text files


def read_normalised(path: Path, what: str, warnings: list[str] | None = None) -> bytes:
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
    nl = np.flatnonzero(buf == NL)
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
        out[start:end] = SPACE
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


def decode_text(b: bytes) -> str:
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("latin-1")


# --------------------------------------------------------------------------------------
# Vectorised line classification and number parsing


@dataclass
class Lines:
    """The lines of a normalised file. All arrays have one entry per line (L lines)."""

    data: bytes
    starts: np.ndarray  # (L,) int32 (int64 for files over 2 GiB) offset of the line's first byte
    ends: np.ndarray  # (L,) same dtype, offset of its "\n"
    first: np.ndarray  # (L,) same dtype, offset of its first non-blank byte (== end if blank)
    cls: np.ndarray  # (L,) int8 line class (V, F, ...)

    @classmethod
    def split(cls, data: bytes) -> "Lines":
        """``data``: normalised text (:func:`read_normalised`: ends in ``\n``)."""
        buf = np.frombuffer(data, np.uint8)
        # offsets as int32 when they fit: 12 bytes a line instead of 24 (a 80 MB file of 10M
        # short lines kept 230 MB of offsets)
        ends = np.flatnonzero(buf == NL).astype(np.int32 if buf.size < 2**31 - 4 else np.int64)
        starts = np.empty_like(ends)
        starts[0] = 0
        starts[1:] = ends[:-1] + 1
        first = starts.copy()
        indented = np.flatnonzero(buf[starts] == SPACE)
        if indented.size:  # rare: only these lines need a search for their first non-blank
            nonblank = np.flatnonzero(buf != SPACE)  # includes the "\n"s, so always found
            first[indented] = nonblank[np.searchsorted(nonblank, starts[indented])]
        # the bytes after a line's first one, reading the final "\n" past the end (a blank, as
        # a separator should be) instead of padding a copy of the file
        last = buf.size - 1
        c0, c1, c2 = buf[first], buf[np.minimum(first + 1, last)], buf[np.minimum(first + 2, last)]
        sep1 = (c1 == SPACE) | (c1 == NL)
        sep2 = (c2 == SPACE) | (c2 == NL)
        kind = np.full(ends.shape, OTHER, np.int8)
        kind[c0 == ord("#")] = COMMENT
        is_v = c0 == ord("v")
        kind[is_v & sep1] = V
        kind[is_v & (c1 == ord("t")) & sep2] = VT
        kind[is_v & (c1 == ord("n")) & sep2] = VN
        kind[(c0 == ord("f")) & sep1] = F
        kind[first == ends] = BLANK
        return cls(data, starts, ends, first, kind)

    def text(self, i: int) -> str:
        return decode_text(self.data[self.starts[i]:self.ends[i]]).strip()

    def region(self, kind: int, keyword_len: int) -> tuple[bytes, np.ndarray]:
        """The bytes of all lines of one class, keywords blanked, each line ending in "\\n".

        Returns (bytes, line numbers (K,) int32, int64 for files over 2 GiB, 0-based, of those
        lines). ``#`` comments at
        the end of the lines are blanked too.
        """
        idx = np.flatnonzero(self.cls == kind).astype(self.starts.dtype)  # int32 when offsets fit
        if idx.size == 0:
            return b"", idx
        buf = np.frombuffer(self.data, np.uint8)
        # runs of consecutive lines of the class: each run's bytes are contiguous in the file
        brk = np.flatnonzero(np.diff(idx) != 1)
        run_first = idx[np.concatenate(([0], brk + 1))]
        run_last = idx[np.concatenate((brk, [idx.size - 1]))]
        b0 = self.starts[run_first].astype(np.int64)
        b1 = self.ends[run_last].astype(np.int64) + 1
        if b0.size == 1:  # one block of lines (the usual file: all v, then all f): one copy
            out = buf[int(b0[0]):int(b1[0])].copy()
            kw = self.first[idx] - int(b0[0])
        else:
            edge = np.zeros(buf.size + 1, np.int8)
            edge[b0] = 1
            edge[b1] -= 1  # runs are apart (another line between), so the running sum is 0 or 1
            out = buf[np.cumsum(edge[:-1], dtype=np.int8).view(bool)]
            del edge
            # a line's keyword moves left by the bytes dropped before its run
            lengths = b1 - b0
            shift = b0 - (np.cumsum(lengths) - lengths)
            kw = self.first[idx] - np.repeat(shift, np.diff(np.concatenate(([0], brk + 1, [idx.size]))))
        for k in range(keyword_len):
            out[kw + k] = SPACE
        del kw
        if b"#" in self.data:
            _blank_comments(out)
        return out.tobytes(), idx


def _blank_comments(arr: np.ndarray) -> None:
    """In place: blank every byte from a "#" to the end of its line (arr (B,) uint8)."""
    hashes = np.flatnonzero(arr == ord("#"))
    if hashes.size == 0:
        return
    nl = np.flatnonzero(arr == NL)  # the region ends in "\n": every hash has one after it
    line_of = np.searchsorted(nl, hashes)
    firsts = np.concatenate(([True], line_of[1:] != line_of[:-1]))  # the first hash of each line
    start, stop = hashes[firsts], nl[line_of[firsts]]
    edge = np.zeros(arr.size + 1, np.int8)  # one range a line: the running sum is 0 or 1
    edge[start] = 1
    edge[stop] -= 1
    arr[np.cumsum(edge[:-1], dtype=np.int8).view(bool)] = SPACE


@dataclass
class Tokens:
    """Whitespace-separated tokens of a region (bytes, every line ending in "\\n")."""

    starts: np.ndarray  # (T,) int64 offset of each token's first byte
    ends: np.ndarray  # (T,) int64 offset just past each token
    line: np.ndarray  # (T,) int64 region line (0..K-1) of each token
    per_line: np.ndarray  # (K,) int64 tokens on each line


def token_layout(arr: np.ndarray, n_lines: int) -> Tokens:
    """Token boundaries of a region: arr (B,) uint8 holding n_lines lines."""
    if arr.size == 0:
        empty = np.zeros(0, np.int64)
        return Tokens(empty, empty, empty, np.zeros(n_lines, np.int64))
    newline = arr == NL
    blank = (arr == SPACE) | newline
    edge = np.diff(blank.view(np.int8), prepend=np.int8(1), append=np.int8(1))
    starts = np.flatnonzero(edge == -1)  # blank -> non-blank
    ends = np.flatnonzero(edge == 1)  # non-blank -> blank
    nl_pos = np.flatnonzero(newline)
    tok_line = np.searchsorted(nl_pos, starts)  # newlines before the token
    return Tokens(starts, ends, tok_line, np.bincount(tok_line, minlength=n_lines))


_DOT_MINUS_TO_BLANK = bytes.maketrans(b".-", b"  ")
_POW10 = 10.0 ** np.arange(19)
_IPOW10 = 10 ** np.arange(19, dtype=np.int64)


def fast_decimals(text: bytes, arr: np.ndarray, tok: Tokens) -> np.ndarray | None:
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


def parse_floats(text: bytes) -> np.ndarray | None:
    """All numbers of a whitespace-separated byte string as float64, or None if one is bad."""
    if not text.strip():
        return np.zeros(0, np.float64)
    try:
        return np.fromstring(text, dtype=np.float64, sep=" ")
    except ValueError:
        return None


def parse_ints(text: bytes) -> np.ndarray | None:
    if not text.strip():
        return np.zeros(0, np.int64)
    try:
        return np.fromstring(text, dtype=np.int64, sep=" ")
    except ValueError:
        return None


def ragged_to_matrix(values: np.ndarray, counts: np.ndarray, width: int, fill: float) -> np.ndarray:
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


