"""A tiny glTF 2.0 writer for tests: numpy arrays in, .gltf/.bin/.glb files out.

    b = GltfBuilder()
    pos = b.add_accessor(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32))
    b.add_node(mesh=b.add_mesh([{"attributes": {"POSITION": pos}}]))
    path = b.write_gltf(tmp_path / "tri.gltf")

Everything goes into one binary buffer (buffer 0); ``write_gltf`` stores it as an external
.bin (default) or a base64 data URI, ``write_glb`` as the GLB binary chunk. The JSON is kept
in ``b.doc`` as plain dicts, so a test can add or break anything by editing it directly.
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

# numpy dtype -> glTF componentType
COMPONENT_TYPES = {
    np.dtype(np.int8): 5120, np.dtype(np.uint8): 5121, np.dtype(np.int16): 5122,
    np.dtype(np.uint16): 5123, np.dtype(np.uint32): 5125, np.dtype(np.float32): 5126,
}
TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 9: "MAT3", 16: "MAT4"}


class GltfBuilder:
    def __init__(self):
        self.doc: dict = {"asset": {"version": "2.0", "generator": "assetpipe tests"}}
        self.bin = bytearray()

    # -- low level ------------------------------------------------------------------------
    def _list(self, key: str) -> list:
        return self.doc.setdefault(key, [])

    def add_bytes(self, data: bytes) -> int:
        """Append raw bytes to buffer 0 (4-byte aligned); returns their byte offset."""
        self.bin.extend(b"\0" * (-len(self.bin) % 4))
        offset = len(self.bin)
        self.bin.extend(data)
        return offset

    def add_view(self, data: bytes, *, stride: int | None = None, target: int | None = None,
                 extensions: dict | None = None) -> int:
        """A bufferView over ``data`` appended to buffer 0."""
        view = {"buffer": 0, "byteOffset": self.add_bytes(bytes(data)), "byteLength": len(data)}
        if stride is not None:
            view["byteStride"] = stride
        if target is not None:
            view["target"] = target
        if extensions:
            view["extensions"] = extensions
        views = self._list("bufferViews")
        views.append(view)
        return len(views) - 1

    def add_accessor(self, array=None, *, view: int | None = None, byte_offset: int = 0,
                     component_type: int | None = None, type: str | None = None,
                     count: int | None = None, normalized: bool = False, **extra) -> int:
        """An accessor. With ``array`` (and no ``view``) the array's bytes get their own view;
        componentType/type/count are taken from the array unless given."""
        arr = None if array is None else np.asarray(array)
        if arr is not None:
            ncomp = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
            component_type = component_type or COMPONENT_TYPES[arr.dtype]
            type = type or TYPES[ncomp]
            count = arr.shape[0] if count is None else count
            if view is None:
                view = self.add_view(np.ascontiguousarray(arr).astype(arr.dtype.newbyteorder("<")).tobytes())
        acc = {"componentType": component_type, "type": type, "count": count}
        if view is not None:
            acc["bufferView"] = view
        if byte_offset:
            acc["byteOffset"] = byte_offset
        if normalized:
            acc["normalized"] = True
        if arr is not None and type in ("VEC3",) and arr.size and arr.dtype.kind == "f" and np.isfinite(arr).all():
            acc["min"] = [float(v) for v in arr.min(axis=0)]
            acc["max"] = [float(v) for v in arr.max(axis=0)]
        acc.update(extra)
        accessors = self._list("accessors")
        accessors.append(acc)
        return len(accessors) - 1

    # -- scene ----------------------------------------------------------------------------
    def add_mesh(self, primitives: list[dict], **extra) -> int:
        meshes = self._list("meshes")
        meshes.append({"primitives": primitives, **extra})
        return len(meshes) - 1

    def add_triangles(self, positions, indices=None, *, mode: int | None = None,
                      material: int | None = None, **attributes) -> int:
        """A mesh of one primitive; ``attributes`` maps glTF names (NORMAL, TEXCOORD_0...) to arrays."""
        prim: dict = {"attributes": {"POSITION": self.add_accessor(np.asarray(positions, np.float32))}}
        for name, arr in attributes.items():
            prim["attributes"][name] = self.add_accessor(np.asarray(arr, np.float32))
        if indices is not None:
            prim["indices"] = self.add_accessor(np.asarray(indices, np.uint16).reshape(-1))
        if mode is not None:
            prim["mode"] = mode
        if material is not None:
            prim["material"] = material
        return self.add_mesh([prim])

    def add_node(self, *, root: bool = True, **fields) -> int:
        """A node (fields as in glTF: mesh, children, translation, rotation, scale, matrix...).
        ``root`` also lists it in scene 0."""
        nodes = self._list("nodes")
        nodes.append({k: v for k, v in fields.items() if v is not None})
        index = len(nodes) - 1
        if root:
            scenes = self._list("scenes")
            if not scenes:
                scenes.append({"nodes": []})
                self.doc["scene"] = 0
            scenes[0]["nodes"].append(index)
        return index

    def add_material(self, **fields) -> int:
        materials = self._list("materials")
        materials.append(fields)
        return len(materials) - 1

    def add_texture(self, *, uri: str | None = None, data: bytes | None = None,
                    mime: str = "image/png", sampler: dict | None = None) -> int:
        """A texture over a new image: a file ``uri``, or ``data`` in a bufferView."""
        image: dict = {"uri": uri} if uri is not None else {"bufferView": self.add_view(data), "mimeType": mime}
        images = self._list("images")
        images.append(image)
        tex: dict = {"source": len(images) - 1}
        if sampler is not None:
            samplers = self._list("samplers")
            samplers.append(sampler)
            tex["sampler"] = len(samplers) - 1
        textures = self._list("textures")
        textures.append(tex)
        return len(textures) - 1

    # -- output ---------------------------------------------------------------------------
    def _json(self, buffer: dict | None) -> dict:
        doc = json.loads(json.dumps(self.doc))
        if buffer is not None:
            doc["buffers"] = [buffer]
        return doc

    def write_gltf(self, path: Path, *, embed: bool = False, bin_name: str | None = None) -> Path:
        """Write ``path`` (.gltf) with buffer 0 as ``<stem>.bin`` beside it (or a data URI)."""
        path = Path(path)
        buffer = None
        if self.bin or "buffers" not in self.doc:
            if embed:
                uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.bin)).decode()
            else:
                uri = bin_name or path.with_suffix(".bin").name
                (path.parent / uri).write_bytes(bytes(self.bin))
            buffer = {"uri": uri, "byteLength": len(self.bin)}
        path.write_text(json.dumps(self._json(buffer), indent=1))
        return path

    def glb_bytes(self) -> bytes:
        js = json.dumps(self._json({"byteLength": len(self.bin)})).encode()
        js += b" " * (-len(js) % 4)
        blob = bytes(self.bin) + b"\0" * (-len(self.bin) % 4)
        chunks = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
        return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks

    def write_glb(self, path: Path) -> Path:
        path = Path(path)
        path.write_bytes(self.glb_bytes())
        return path


# A valid 1x1 RGBA PNG (for image tests that only need the bytes to sniff as PNG).
PNG_1X1 = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8DwHwAFBQIAX8jx0gAAAABJRU5ErkJggg==")
