"""Decoding glTF buffers, buffer views and accessors into numpy arrays.

Everything is decoded with ``np.frombuffer`` and strided views; no Python loop runs per
element. Bounds are checked before any view is made, so a malformed file raises an
:class:`AssetError` naming the accessor instead of reading garbage.
"""

from __future__ import annotations

import base64
import binascii
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from assetpipe.core.errors import AssetError, MissingFileError, UnsupportedError
from assetpipe.pipelines.budgets import DEFAULT_INPUT_BUDGETS, describe_bytes
from assetpipe.pipelines.image_source import resolve_inside

COMPONENT_DTYPES = {
    5120: np.dtype(np.int8),
    5121: np.dtype(np.uint8),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# Divisors for normalized integers (glTF 2.0 spec, "Animations" / accessor normalization).
_NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0, 5125: 4294967295.0}

MAX_DATA_URI_BYTES = 512 * 1024 * 1024


def decode_data_uri(uri: str, source: Path, what: str) -> bytes:
    """The bytes of a ``data:`` URI (base64 only, size-bounded before decoding)."""
    header, _, payload = uri.partition(",")
    if ";base64" not in header:
        raise AssetError(source, f"{what}: only base64 data URIs are supported")
    if len(payload) * 3 // 4 > MAX_DATA_URI_BYTES:
        raise AssetError(source, f"{what}: data URI larger than {MAX_DATA_URI_BYTES} bytes")
    payload = "".join(payload.split())  # line breaks inside a data URI are tolerated
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise AssetError(source, f"{what}: invalid base64 data URI ({exc})") from None


def uri_scheme(uri: str) -> str | None:
    """The scheme of a URI other than ``data:`` (``file``, ``http``, ...), or None for a relative
    path. A Windows drive letter (``C:``) counts as a scheme too: both are refused."""
    head = uri.split("/", 1)[0]
    if ":" in head:
        return head.split(":", 1)[0].lower()
    return None


def check_uri(uri: str, source: Path, what: str) -> None:
    """Refuse a URI with a scheme (``file://``, ``http://``, ``C:``): the one policy for buffers
    and images alike is that a model reads only relative paths inside its folder and data URIs."""
    scheme = uri_scheme(uri)
    if scheme is not None and scheme != "data":
        raise UnsupportedError(source, f"{what}: refuses the URI {uri[:80]!r}: only relative paths inside the "
                                       "model's folder and data: URIs are read")


def data_uri_mime(uri: str) -> str | None:
    header = uri.partition(",")[0]
    return header[5:].split(";")[0] or None


class AccessorReader:
    """Reads a glTF document's accessors as numpy arrays.

    ``gltf`` is the document view (:mod:`pipelines.gltf_document`); ``glb_blob`` the binary
    chunk of a .glb (or None).
    Files read (external buffers) are recorded in ``self.dependencies``.
    """

    def __init__(self, gltf, source: Path, glb_blob: bytes | None, max_bytes: int = DEFAULT_INPUT_BUDGETS.max_model_bytes):
        self.max_bytes = max_bytes
        self.gltf = gltf
        self.source = source
        self.base_dir = source.parent
        self.glb_blob = glb_blob
        self.dependencies: list[Path] = []
        self._buffers: dict[int, bytes] = {}
        self._views: dict[int, memoryview] = {}

    # -- buffers and views --------------------------------------------------------------
    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        buffers = self.gltf.buffers or []
        if not 0 <= index < len(buffers):
            raise AssetError(self.source, f"buffer {index} does not exist")
        buf = buffers[index]
        uri = buf.uri
        if uri is None:
            if self.glb_blob is None:
                raise AssetError(self.source, f"buffer {index} has no uri and the file has no GLB binary chunk")
            data = self.glb_blob
        elif uri.startswith("data:"):
            data = decode_data_uri(uri, self.source, f"buffer {index}")
        else:
            check_uri(uri, self.source, f"buffer {index}")
            path = resolve_inside(self.base_dir, unquote(uri), self.source)
            if not path.is_file():
                raise MissingFileError(self.source, f"buffer {index}: file {uri!r} not found")
            data = path.read_bytes()
            self.dependencies.append(path)
            if data.startswith(b"version https://git-lfs"):
                raise AssetError(self.source, f"buffer {index}: {uri!r} is a Git LFS pointer, not data (run git lfs pull)")
        if buf.byteLength is not None and len(data) < buf.byteLength:
            raise AssetError(self.source, f"buffer {index} has {len(data)} bytes, fewer than its byteLength {buf.byteLength}")
        self._buffers[index] = data
        return data

    def buffer_view(self, index: int) -> memoryview:
        """The bytes of a buffer view (decompressed when EXT_meshopt_compression is used)."""
        if index in self._views:
            return self._views[index]
        views = self.gltf.bufferViews or []
        if not 0 <= index < len(views):
            raise AssetError(self.source, f"bufferView {index} does not exist")
        view = views[index]
        ext = (view.extensions or {}).get("EXT_meshopt_compression") or (view.extensions or {}).get(
            "KHR_meshopt_compression")
        if ext is not None:
            data = memoryview(self._decode_meshopt(index, ext))
        else:
            buf = self.buffer(view.buffer)
            start = view.byteOffset or 0
            end = start + view.byteLength
            if end > len(buf):
                raise AssetError(self.source, f"bufferView {index} (bytes {start}..{end}) runs past the end of buffer {view.buffer} ({len(buf)} bytes)")
            data = memoryview(buf)[start:end]
        self._views[index] = data
        return data

    def _decode_meshopt(self, index: int, ext: dict) -> bytes:
        import meshoptimizer

        if not isinstance(ext, dict) or not all(
                isinstance(ext.get(k, 0), int) and not isinstance(ext.get(k, 0), bool) and ext.get(k, 0) >= 0
                for k in ("buffer", "byteOffset", "byteLength", "count", "byteStride")) or \
                not all(k in ext for k in ("buffer", "byteLength", "count", "byteStride")):
            raise AssetError(self.source, f"bufferView {index}: EXT_meshopt_compression needs non-negative integer "
                                          "buffer, byteLength, count and byteStride")
        buf = self.buffer(ext["buffer"])
        start = ext.get("byteOffset", 0)
        if start + ext["byteLength"] > len(buf):
            raise AssetError(self.source, f"bufferView {index}: EXT_meshopt_compression data runs past the end of buffer {ext['buffer']}")
        src = bytes(buf[start:start + ext["byteLength"]])
        count, stride = int(ext["count"]), int(ext["byteStride"])
        if count * max(stride, 1) > self.max_bytes:
            raise AssetError(self.source, f"bufferView {index}: EXT_meshopt_compression declares {count} x {stride} "
                                          f"bytes, over the model's memory budget of {describe_bytes(self.max_bytes)}")
        mode, filt = ext.get("mode", "ATTRIBUTES"), ext.get("filter", "NONE")
        try:
            if mode == "ATTRIBUTES":
                # Without ``dtype`` the wrapper allocates count * stride bytes (returned as a
                # float32 view); with dtype=np.uint8 it allocates only ``count`` bytes and the
                # decoder writes past them.
                out = meshoptimizer.decode_vertex_buffer(count, stride, src)
                out = np.ascontiguousarray(out).view(np.uint8).reshape(-1)
                if filt == "OCTAHEDRAL":
                    out = meshoptimizer.decode_filter_oct(out, count, stride)
                elif filt == "QUATERNION":
                    out = meshoptimizer.decode_filter_quat(out, count, stride)
                elif filt == "EXPONENTIAL":
                    out = meshoptimizer.decode_filter_exp(out, count, stride)
                elif filt != "NONE":
                    raise UnsupportedError(self.source, f"bufferView {index}: EXT_meshopt_compression filter {filt!r} is not supported")
            elif mode == "TRIANGLES":
                out = meshoptimizer.decode_index_buffer(count, stride, src)
            elif mode == "INDICES":
                out = meshoptimizer.decode_index_sequence(count, stride, src)
            else:
                raise UnsupportedError(self.source, f"bufferView {index}: EXT_meshopt_compression mode {mode!r} is not supported")
        except (ValueError, RuntimeError) as exc:
            raise AssetError(self.source, f"bufferView {index}: EXT_meshopt_compression data does not decode ({exc})") from None
        out = np.ascontiguousarray(out)
        if mode != "ATTRIBUTES":
            # The decoder writes ``stride``-byte indices into the wrapper's uint32 array: the
            # first count * stride bytes are the data (casting the uint32s would mix pairs).
            if stride not in (2, 4):
                raise AssetError(self.source, f"bufferView {index}: EXT_meshopt_compression index byteStride {stride} is not 2 or 4")
            out = out.view(np.uint8)[: count * stride]
        return out.tobytes()

    # -- accessors ----------------------------------------------------------------------
    def info(self, index: int) -> tuple[np.dtype, int, int]:
        """(component dtype, components, count) of accessor ``index`` as declared, checked."""
        accessors = self.gltf.accessors or []
        if not isinstance(index, int) or not 0 <= index < len(accessors):
            raise AssetError(self.source, f"accessor {index} does not exist")
        acc = accessors[index]
        if acc.componentType not in COMPONENT_DTYPES:
            raise AssetError(self.source, f"accessor {index} has unknown componentType {acc.componentType}")
        if acc.type not in TYPE_COMPONENTS:
            raise AssetError(self.source, f"accessor {index} has unknown type {acc.type!r}")
        return COMPONENT_DTYPES[acc.componentType], TYPE_COMPONENTS[acc.type], int(acc.count)

    def decoded_bytes(self, index: int) -> int:
        """Bytes accessor ``index`` takes once decoded (float64 or int64 elements): from the
        declared count, before anything is read."""
        _, ncomp, count = self.info(index)
        return count * ncomp * 8

    def accessor(self, index: int, *, as_float: bool = True) -> np.ndarray:
        """Accessor ``index`` as an array of shape (count, components) (or (count,) for scalars).

        ``as_float``: float64 with normalized integers mapped to [0,1]/[-1,1] as the spec says;
        otherwise the raw integer dtype (for indices and joints).
        """
        dtype, ncomp, count = self.info(index)
        acc = self.gltf.accessors[index]
        if count < 0:
            raise AssetError(self.source, f"accessor {index} has a negative count")
        if count * ncomp * 8 > self.max_bytes:
            raise AssetError(self.source, f"accessor {index} declares {count} x {ncomp} values "
                                          f"({describe_bytes(count * ncomp * 8)} decoded), over the model's memory "
                                          f"budget of {describe_bytes(self.max_bytes)}")
        if acc.bufferView is None:
            arr = np.zeros((count, ncomp), dtype=dtype)
        else:
            arr = self._strided(index, acc.bufferView, acc.byteOffset or 0, dtype, ncomp, count)
        if acc.sparse is not None and acc.sparse.count:
            arr = self._apply_sparse(index, acc, arr, dtype, ncomp)
        if as_float:
            out = arr.astype(np.float64)
            if acc.normalized and acc.componentType != 5126:
                out /= _NORMALIZE[acc.componentType]
                if dtype.kind == "i":
                    np.maximum(out, -1.0, out=out)
            arr = out
        return arr[:, 0] if ncomp == 1 else arr

    def _strided(self, index: int, view_index: int, offset: int, dtype: np.dtype, ncomp: int, count: int) -> np.ndarray:
        view = self.buffer_view(view_index)
        elem = dtype.itemsize * ncomp
        stride = (self.gltf.bufferViews[view_index].byteStride or 0) or elem
        if stride < elem:
            raise AssetError(self.source, f"accessor {index}: byteStride {stride} is smaller than its element size {elem}")
        if count == 0:
            return np.zeros((0, ncomp), dtype=dtype)
        need = offset + stride * (count - 1) + elem
        if need > len(view):
            raise AssetError(self.source, f"accessor {index} needs {need} bytes but bufferView {view_index} has {len(view)}")
        raw = np.frombuffer(view, dtype=np.uint8, count=need - offset, offset=offset)
        if stride == elem:
            return raw.view(dtype).reshape(count, ncomp)
        # Strided (interleaved) data: gather rows of ``elem`` bytes every ``stride`` bytes.
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, elem), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, ncomp)

    def _apply_sparse(self, index: int, acc, base: np.ndarray, dtype: np.dtype, ncomp: int) -> np.ndarray:
        sp = acc.sparse
        n = int(sp.count)
        idx_dtype = COMPONENT_DTYPES.get(sp.indices.componentType)
        if idx_dtype is None or idx_dtype.kind != "u":
            raise AssetError(self.source, f"accessor {index}: sparse indices have invalid componentType")
        idx = self._strided(index, sp.indices.bufferView, sp.indices.byteOffset or 0, idx_dtype, 1, n)[:, 0]
        vals = self._strided(index, sp.values.bufferView, sp.values.byteOffset or 0, dtype, ncomp, n)
        if n and int(idx.max()) >= base.shape[0]:
            raise AssetError(self.source, f"accessor {index}: sparse index {int(idx.max())} is out of range (count {base.shape[0]})")
        out = np.array(base, copy=True)
        out[idx.astype(np.int64)] = vals
        return out
