"""Structured fuzzing of the importers and the image decoder (issue #13), driven by hypothesis.

Used by ``tests/test_fuzz.py`` (a CI-sized run) and ``benchmarks/fuzz.py`` (a long run). Run as a
program it fuzzes in *this* process, so call it in a subprocess: it limits its own address space
(``resource.setrlimit(RLIMIT_AS)``) and every case's time (``SIGALRM``), so a memory blow-up
or a hang is an outcome, not a dead machine.

    python tests/fuzz_inputs.py --cases 300 --seed 0 --builds 4 --report out.json

Inputs: glTF documents (``.gltf`` + ``.bin``, embedded data URIs, ``.glb``) from seed models
built with :mod:`gltf_builder`, mutated structurally (keys deleted, values replaced by wrong
types, negatives, huge counts, NaN tokens) and at the byte level (flips, truncation); OBJ files
generated line by line from the grammar (numbers in every form, indices in and out of range,
junk and binary lines, groups, ``mtllib``) with an MTL file and a PNG texture beside them; PNG
files with generated headers, chunks and (in)valid pixel streams, and JPEG files (a small one
with an EXIF block, its bytes changed, cut short, zeroed or repeated), through
:func:`pipelines.texture_decode.decode_image`.

Outcomes per case: ``built`` (imported with no warning), ``warning``, ``error`` (one
:class:`AssetError` line naming the file), and the failures ``internal`` (any other exception,
or an error message of several lines or naming no file), ``timeout``, ``memory`` and
``pywarning`` (a Python warning such as numpy's RuntimeWarning, which adds lines to the output). For a
slice of cases the real ``assetpipe build`` runs on a folder with the bad model beside a good
one: ``build-ok`` when it exits 0 or 1 with the good model built and no internal error.
"""

from __future__ import annotations

import argparse
import base64
import collections
import copy
import io
import json
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import traceback
import warnings as warnings_module
import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import numpy as np  # noqa: E402
from hypothesis import HealthCheck, given, seed as hypothesis_seed, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from assetpipe.core.errors import AssetError  # noqa: E402
from gltf_builder import GltfBuilder  # noqa: E402
from json_edits import value_paths  # noqa: E402

FAILURES = ("internal", "timeout", "memory", "pywarning")
CASE_SECONDS = 20  # a case's time limit (every legitimate case here takes well under a second)
ADDRESS_SPACE = 6 << 30  # the fuzzing process's address-space limit (numpy/OpenCV map ~1.5 GB at start)


def _one_in(draw, n: int) -> bool:
    """True about once in ``n`` draws (hypothesis favours 0 and small integers, so
    ``integers(0, n - 1) == 0`` would come up far more often)."""
    return draw(st.sampled_from([False] * (n - 1) + [True]))


# -- PNG ------------------------------------------------------------------------------------------

def _chunk(kind: bytes, body: bytes, good_crc: bool = True) -> bytes:
    crc = zlib.crc32(kind + body) ^ (0 if good_crc else 1)
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc & 0xFFFFFFFF)


@st.composite
def png_bytes(draw) -> bytes:
    """A PNG with a generated header and a pixel stream that is valid, short, long or garbage."""
    small = st.integers(1, 64)
    width = draw(st.one_of(small, small, small, st.sampled_from([0, 13000, 16384, 16385, 70000, 2 ** 31 - 1])))
    height = draw(st.one_of(small, small, small, st.sampled_from([0, 13000, 16384, 16385, 70000, 2 ** 31 - 1])))
    valid = [(0, 1), (0, 2), (0, 4), (0, 8), (0, 16), (2, 8), (2, 16), (3, 1), (3, 2), (3, 4), (3, 8),
             (4, 8), (4, 16), (6, 8), (6, 16)]
    colour, depth = draw(st.one_of(st.sampled_from(valid), st.sampled_from(valid),
                                   st.tuples(st.sampled_from([0, 2, 3, 4, 5, 6]), st.sampled_from([1, 3, 8, 16]))))
    channels = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(colour, 4)
    body = bytearray(b"\x89PNG\r\n\x1a\n")
    body += _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0,
                                        draw(st.sampled_from([0, 0, 0, 1, 2]))), not _one_in(draw, 10))
    if colour == 3:
        body += _chunk(b"PLTE", draw(st.one_of(st.just(bytes(range(48))), st.binary(max_size=30))))
    if _one_in(draw, 5):
        body += _chunk(b"tRNS", draw(st.binary(max_size=8)))
    row_bytes = 1 + (width * channels * depth + 7) // 8
    kind = draw(st.sampled_from(["valid", "valid", "short", "garbage", "none"]))
    if kind in ("valid", "short") and width * height <= 64 * 64:
        rows = draw(st.binary(min_size=row_bytes * height, max_size=row_bytes * height)) if row_bytes * height < 20000 \
            else bytes(row_bytes * height)
        data = zlib.compress(rows)
        if kind == "short":
            data = data[: draw(st.integers(0, max(len(data) - 1, 0)))]
        body += _chunk(b"IDAT", data)
    elif kind == "garbage":
        body += _chunk(b"IDAT", draw(st.binary(max_size=200)))
    elif kind != "none":  # a header claiming megapixels over a few bytes of zeros
        body += _chunk(b"IDAT", zlib.compress(bytes(min(row_bytes, 1 << 16))))
    body += _chunk(b"IEND", b"")
    out = bytes(body)
    flips = draw(st.lists(st.tuples(st.integers(0, 1 << 30), st.integers(0, 255)), max_size=3))
    if flips and _one_in(draw, 3):
        b = bytearray(out)
        for pos, val in flips:
            b[pos % len(b)] = val
        out = bytes(b)
    if _one_in(draw, 10):
        out = out[: draw(st.integers(0, len(out)))]
    return out


def good_png() -> bytes:
    rows = b"".join(b"\x00" + b"".join(bytes([(x * 60) % 256, (y * 60) % 256, 128, 255]) for x in range(4)) for y in range(4))
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 6, 0, 0, 0)) + \
        _chunk(b"IDAT", zlib.compress(rows)) + _chunk(b"IEND", b"")


_GOOD_JPEG: list[bytes] = []


def good_jpeg() -> bytes:
    """A 16x16 JPEG with an EXIF block (resolution, software, date), made once by Pillow."""
    if not _GOOD_JPEG:
        from PIL import Image

        exif = Image.Exif()
        exif[282], exif[283], exif[305], exif[306] = 72.0, 72.0, "assetpipe", "2026:11:26 00:00:00"
        pixels = np.indices((16, 16, 3)).sum(axis=0).astype(np.uint8) * 8
        buf = io.BytesIO()
        Image.fromarray(pixels).save(buf, "JPEG", exif=exif.tobytes(), quality=90)
        _GOOD_JPEG.append(buf.getvalue())
    return _GOOD_JPEG[0]


@st.composite
def jpeg_bytes(draw) -> bytes:
    """:func:`good_jpeg` with bytes changed (mostly in its headers), cut short, zeroed or repeated."""
    b = bytearray(good_jpeg())
    op = draw(st.sampled_from(["header", "header", "anywhere", "cut", "zeros", "repeat"]))
    if op in ("header", "anywhere"):
        end = 300 if op == "header" else len(b)
        for pos, val in draw(st.lists(st.tuples(st.integers(2, end - 1), st.integers(0, 255)), min_size=1, max_size=8)):
            b[pos] = val
    elif op == "cut":
        b = b[: draw(st.integers(0, len(b) - 1))]
    elif op == "zeros":
        at = draw(st.integers(0, len(b) - 1))
        b[at:at + draw(st.integers(1, 400))] = bytes(len(b[at:at + 400]))[: len(b[at:at + 400])]
    else:
        at = draw(st.integers(2, len(b) - 1))
        b = b[:at] + b[at - draw(st.integers(1, min(at, 300))):]
    return bytes(b)


# -- glTF -----------------------------------------------------------------------------------------

#: the kinds of sound glTF documents the cases start from (:func:`_seed_gltf`)
SEED_KINDS = 4


def _seed_gltf(kind: int) -> GltfBuilder:
    b = GltfBuilder()
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    if kind == 0:  # textured, indexed, normals and UVs, TRS node
        tex = b.add_texture(data=good_png())
        mat = b.add_material(pbrMetallicRoughness={"baseColorTexture": {"index": tex}}, alphaMode="MASK")
        mesh = b.add_triangles(quad, [0, 1, 2, 0, 2, 3], material=mat, NORMAL=np.tile([0, 0, 1], (4, 1)),
                               TEXCOORD_0=quad[:, :2])
        b.add_node(mesh=mesh, translation=[1, 2, 3], rotation=[0, 0, 0.7071, 0.7071], scale=[2, 2, 2])
    elif kind == 1:  # hierarchy sharing a mesh, a strip, a matrix
        mesh = b.add_triangles(quad[[0, 1, 3, 2]], mode=5)
        a = b.add_node(mesh=mesh, root=False)
        c = b.add_node(mesh=mesh, root=False, translation=[2, 0, 0])
        b.add_node(children=[a, c], matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 5, 0, 0, 1])
    elif kind == 3:  # every material part the importer reads: PBR and spec-gloss, transforms
        tex = b.add_texture(data=good_png(), sampler={"magFilter": 9729, "wrapS": 33071})
        info = {"index": tex, "texCoord": 0, "extensions": {"KHR_texture_transform": {
            "offset": [0.5, 0], "rotation": 0.3, "scale": [2, 2], "texCoord": 0}}}
        mat = b.add_material(
            pbrMetallicRoughness={"baseColorTexture": info, "baseColorFactor": [1, 0.5, 0.5, 1],
                                  "metallicRoughnessTexture": {"index": tex}, "metallicFactor": 0.2,
                                  "roughnessFactor": 0.7},
            normalTexture={"index": tex, "scale": 1.0}, occlusionTexture={"index": tex, "strength": 0.5},
            emissiveTexture={"index": tex}, emissiveFactor=[0.1, 0.1, 0.1], alphaMode="BLEND",
            alphaCutoff=0.4, doubleSided=True, name="m",
            extensions={"KHR_materials_pbrSpecularGlossiness": {
                "diffuseTexture": {"index": tex}, "diffuseFactor": [1, 1, 1, 1],
                "specularGlossinessTexture": {"index": tex}, "specularFactor": [1, 1, 1],
                "glossinessFactor": 0.5}})
        mesh = b.add_triangles(quad, [0, 1, 2, 0, 2, 3], material=mat, NORMAL=np.tile([0, 0, 1], (4, 1)),
                               TEXCOORD_0=quad[:, :2])
        b.add_node(mesh=mesh)
        b.doc["extensionsUsed"] = ["KHR_texture_transform", "KHR_materials_pbrSpecularGlossiness"]
    else:  # sparse accessor and a morph target
        pos = b.add_accessor(quad)
        idx_view = b.add_view(np.array([1], np.uint16).tobytes())
        val_view = b.add_view(np.array([[0, 0, 1]], np.float32).tobytes())
        target = b.add_accessor(type="VEC3", component_type=5126, count=4,
                                sparse={"count": 1, "indices": {"bufferView": idx_view, "componentType": 5123},
                                        "values": {"bufferView": val_view}})
        ind = b.add_accessor(np.array([0, 1, 2, 0, 2, 3], np.uint32))
        mesh = b.add_mesh([{"attributes": {"POSITION": pos}, "indices": ind, "targets": [{"POSITION": target}]}],
                          weights=[0.5])
        b.add_node(mesh=mesh)
    return b


_VALUES = st.sampled_from([None, -1, 0, 1, 3, 7, 2 ** 31, 2 ** 64, 10 ** 9, 30_000_000, 1e300, -1e300, 3e38, 0.5,
                           "x", "", [], {}, True, [1e39, 0, 0], [0, 0, 0, 0], {"index": 0},
                           "data:application/octet-stream;base64,@@", "file:///etc/passwd", "../x.bin"])


def _mutate_doc(draw, doc: dict) -> dict:
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p in value_paths(doc) if p and p[0] != "asset"]
        if not paths:
            break
        path = paths[draw(st.integers(0, len(paths) - 1))]
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        op = draw(st.sampled_from(["delete", "replace", "replace", "replace", "negate", "grow"]))
        if op == "delete":
            del parent[key]
        elif op == "replace":
            parent[key] = copy.deepcopy(draw(_VALUES))  # the pool's lists and dicts are shared
        elif op == "negate" and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
            parent[key] = -parent[key] - 1
        elif op == "grow" and isinstance(parent[key], int) and not isinstance(parent[key], bool):
            parent[key] = parent[key] * draw(st.sampled_from([2, 1000, 10 ** 6, 10 ** 9]))
        elif op == "grow" and isinstance(parent[key], list) and parent[key]:
            parent[key] = parent[key] * draw(st.integers(2, 5))
    return doc


def _flip(draw, data: bytes, max_flips: int = 4) -> bytes:
    b = bytearray(data)
    for _ in range(draw(st.integers(1, max_flips))):
        if b:
            b[draw(st.integers(0, len(b) - 1))] = draw(st.integers(0, 255))
    return bytes(b)


@st.composite
def gltf_case(draw) -> dict[str, bytes]:
    """Files of one glTF case: {name: bytes}; the model is the one ending .gltf/.glb."""
    b = _seed_gltf(draw(st.integers(0, SEED_KINDS - 1)))
    container = draw(st.sampled_from(["gltf", "embedded", "glb"]))
    structural = not _one_in(draw, 4)
    files: dict[str, bytes] = {}
    if container == "glb":
        doc = b._json({"byteLength": len(b.bin)})
    elif container == "embedded":
        doc = b._json({"uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(b.bin)).decode(),
                       "byteLength": len(b.bin)})
    else:
        doc = b._json({"uri": "m.bin", "byteLength": len(b.bin)})
        files["m.bin"] = bytes(b.bin)
    if structural:
        doc = _mutate_doc(draw, doc)
    text = json.dumps(doc)
    if _one_in(draw, 6):
        text = text.replace("1.0", draw(st.sampled_from(["NaN", "Infinity", "1e400", "-Infinity"])), 1)
    if _one_in(draw, 8):
        text = text[:-1] + ', "extras": ' + "[" * 5000 + "]" * 5000 + "}"
    js = text.encode()
    blob = bytes(b.bin)
    if not structural or _one_in(draw, 4):
        if draw(st.booleans()):
            blob = _flip(draw, blob) if blob else blob
            if "m.bin" in files:
                files["m.bin"] = blob
        else:
            js = _flip(draw, js)
    if container == "glb":
        js += b" " * (-len(js) % 4)
        blob += b"\0" * (-len(blob) % 4)
        chunks = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + blob
        data = struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks
        if _one_in(draw, 4):
            data = _flip(draw, data) if draw(st.booleans()) else data[: draw(st.integers(0, len(data)))]
        files["m.glb"] = data
    else:
        files["m.gltf"] = js
    return files


# -- OBJ + MTL ------------------------------------------------------------------------------------

_NUM = st.one_of(
    st.integers(-3, 3).map(str), st.integers(-3, 3).map(str), st.integers(-3, 3).map(str),
    st.floats(-10, 10, allow_nan=False).map(lambda f: f"{f:.4f}"),
    st.floats(-10, 10, allow_nan=False).map(lambda f: f"{f:.4f}"),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["1e308", "1e39", "3e38", "-0", "nan", "inf", "1e-320", "0x10", "1,5", "abc", "--1", ".", "1e"]),
)
_IDX = st.one_of(st.integers(1, 4), st.integers(1, 4), st.integers(1, 4), st.integers(-8, 12)).map(str)


@st.composite
def _corner(draw) -> str:
    form = draw(st.sampled_from(["v", "v", "v", "v", "v/t", "v//n", "v/t/n", "v/", "v/t/", "//", "v/t/n/x"]))
    out = form.replace("v", draw(_IDX)).replace("t", draw(_IDX)).replace("n", draw(_IDX))
    return out.replace("x", draw(_IDX))


@st.composite
def obj_line(draw) -> str:
    kind = draw(st.sampled_from(["v", "v", "v", "vt", "vn", "f", "f", "f", "f", "o", "g", "usemtl", "mtllib",
                                 "junk", "binary", "comment", "l", "cont", "s"]))
    if kind in ("v", "vt", "vn"):
        n = draw(st.one_of(st.just({"v": 3, "vt": 2, "vn": 3}[kind]), st.integers(0, 7)))
        return kind + " " + " ".join(draw(_NUM) for _ in range(n))
    if kind == "f":
        corners = draw(st.one_of(st.integers(3, 4), st.integers(1, 12)))
        return "f " + " ".join(draw(_corner()) for _ in range(corners))
    if kind in ("o", "g"):
        return f"{kind} {draw(st.sampled_from(['', 'a', 'b', 'grp with space']))}"
    if kind == "usemtl":
        return f"usemtl {draw(st.sampled_from(['red', 'tex', 'missing', '']))}"
    if kind == "mtllib":
        return f"mtllib {draw(st.sampled_from(['m.mtl', 'm.mtl other.mtl', '../m.mtl', '/etc/passwd', 'nope.mtl']))}"
    if kind == "junk":
        return draw(st.text(max_size=20))
    if kind == "binary":
        return draw(st.binary(max_size=12)).decode("latin-1")
    if kind == "comment":
        return "# " + draw(st.text(max_size=10))
    if kind == "l":
        return "l 1 2"
    if kind == "cont":
        return "f 1 2 \\"
    return "s 1"


_MTL_LINES = st.sampled_from([
    "newmtl red", "newmtl tex", "Kd 1 0 0", "Kd 0 0 0", "Kd nan 1 1", "Kd x", "d 0.5", "Tr 1", "Ke 1 1 1",
    "map_Kd t.png", "map_Kd -clamp on t.png", "map_Kd -o 1 2 t.png", "map_Kd missing.png", "map_Kd ../../etc/passwd",
    "map_Kd /etc/passwd", "map_Kd", "bump -bm 2 t.png", "norm t.png", "map_d t.png", "Pm 2", "Pr x", "\x00\x01junk",
])


@st.composite
def obj_case(draw) -> dict[str, bytes]:
    base = ["v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "vt 0 0", "vt 1 1", "vn 0 0 1", "mtllib m.mtl",
            "usemtl tex", "f 1/1/1 2/2/1 3/2/1", "f 1 3 4"]
    lines = [] if _one_in(draw, 4) else list(base)
    extra = draw(st.lists(obj_line(), max_size=draw(st.sampled_from([3, 3, 25]))))
    for line in extra:
        lines.insert(draw(st.integers(0, len(lines))), line)
    eol = draw(st.sampled_from(["\n", "\n", "\r\n", "\r"]))
    text = eol.join(lines) + (eol if draw(st.booleans()) else "")
    data = text.encode("utf-8", "surrogatepass") if not _one_in(draw, 10) else ("\ufeff" + text).encode("utf-16")
    mtl = "\n".join(draw(st.lists(_MTL_LINES, max_size=12))).encode("latin-1")
    files = {"m.obj": data, "m.mtl": mtl}
    if draw(st.booleans()):
        files["t.png"] = draw(png_bytes()) if draw(st.booleans()) else good_png()
    return files


# -- running a case -------------------------------------------------------------------------------

class _Timeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def classify(fn, model: Path) -> tuple[str, str]:
    """(outcome, detail) of ``fn()``; see the module docstring."""
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_SECONDS)
    caught = warnings_module.catch_warnings(record=True)
    try:
        with caught as seen:
            warnings_module.simplefilter("always")
            result = fn()
        # a Python warning (numpy's RuntimeWarning, ...) would add lines to the build's output
        if seen:
            return "pywarning", "; ".join(f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})"
                                          for w in seen[:3])
    except AssetError as exc:
        text = str(exc)
        if seen:
            return "pywarning", f"{text} + " + "; ".join(f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})"
                                                     for w in seen[:3])
        if "\n" in text or exc.path is None:
            return "internal", f"AssetError not one line naming a file: {text[:300]!r}"
        return "error", text
    except MemoryError:
        return "memory", traceback.format_exc(limit=-3)
    except _Timeout:
        return "timeout", traceback.format_exc(limit=-3)
    except BaseException as exc:  # noqa: BLE001 - the point: anything else is a bug of ours
        return "internal", f"{type(exc).__name__}: {str(exc)[:200]}\n{traceback.format_exc(limit=-4)}"
    finally:
        signal.alarm(0)
    warnings = getattr(result, "warnings", ())  # the model's own warnings: an expected outcome
    return ("warning" if warnings else "built"), "; ".join(warnings)[:300]


def write_case(folder: Path, files: dict[str, bytes]) -> Path:
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return next(folder / n for n in files if n.endswith((".gltf", ".glb", ".obj")))


def run_import(files: dict[str, bytes], folder: Path) -> tuple[str, str]:
    from assetpipe.pipelines.import_gltf import import_gltf
    from assetpipe.pipelines.import_obj import import_obj

    model = write_case(folder, files)
    fn = import_obj if model.suffix == ".obj" else import_gltf
    return classify(lambda: fn(model), model)


def run_png(data: bytes) -> tuple[str, str]:
    from assetpipe.core.hashing import digest_bytes
    from assetpipe.pipelines.model import ImageSource
    from assetpipe.pipelines.texture_decode import decode_image

    image = ImageSource(name="t.png", data=data, mime="image/png", origin="fuzz/t.png", digest=digest_bytes(data))
    return classify(lambda: decode_image(image), Path("fuzz/t.png"))


def run_jpeg(data: bytes) -> tuple[str, str]:
    from assetpipe.core.hashing import digest_bytes
    from assetpipe.pipelines.model import ImageSource
    from assetpipe.pipelines.texture_decode import decode_image

    image = ImageSource(name="t.jpg", data=data, mime="image/jpeg", origin="fuzz/t.jpg", digest=digest_bytes(data))
    return classify(lambda: decode_image(image), Path("fuzz/t.jpg"))


def run_build(files: dict[str, bytes], folder: Path) -> tuple[str, str]:
    """The real ``assetpipe build`` on the bad model beside a good one (in its own folder)."""
    bad = write_case(folder / "in" / "bad", files)
    good_dir = folder / "in" / "good"
    good_dir.mkdir(parents=True)
    (good_dir / "good.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    out = folder / "out"
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    cmd = [sys.executable, "-m", "assetpipe.cli", "build", str(folder / "in"), "-o", str(out), "--no-lod",
           "--cache", str(folder / "cache"), "-q", "--json", str(folder / "report.json")]
    try:
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return "build-timeout", str(bad)
    text = proc.stdout + proc.stderr
    good_built = any(p.name.startswith("good") and p.suffix == ".json" for p in out.rglob("*")) if out.exists() else False
    if proc.returncode not in (0, 1) or "internal error" in text.lower() or "Traceback" in text or not good_built:
        return "build-failed", f"exit {proc.returncode}, good built: {good_built}: {text[-600:]}"
    return "build-ok", f"exit {proc.returncode}"


#: the kinds of cases, each a share of the run
KINDS = ("gltf", "obj", "png", "jpeg")


def fuzz(cases: int, seed: int, builds: int, workdir: Path) -> dict:
    """Run ``cases`` generated cases (a quarter each glTF, OBJ, PNG, JPEG) and ``builds`` build checks."""
    counts: dict[str, collections.Counter] = {k: collections.Counter() for k in KINDS + ("build",)}
    failures: list[dict] = []
    per_kind = max(1, cases // len(KINDS))
    build_every = max(1, (2 * per_kind) // builds) if builds else 0
    n = {"i": 0}

    def record(kind: str, outcome: str, detail: str, files=None) -> None:
        counts[kind][outcome] += 1
        if outcome in FAILURES or outcome.startswith("build-") and outcome != "build-ok":
            failures.append({"kind": kind, "outcome": outcome, "detail": detail,
                             "files": {k: base64.b64encode(v).decode() for k, v in (files or {}).items()}})

    common = dict(max_examples=per_kind, database=None, deadline=None, suppress_health_check=list(HealthCheck))

    def model_case(kind: str, files: dict[str, bytes]) -> None:
        n["i"] += 1
        outcome, detail = run_import(files, workdir / "case")
        record(kind, outcome, detail, files)
        if build_every and n["i"] % build_every == 0 and sum(counts["build"].values()) < builds:
            b_out, b_detail = run_build(files, workdir / f"build{n['i']}")
            record("build", b_out, b_detail, files)
            shutil.rmtree(workdir / f"build{n['i']}", ignore_errors=True)

    @hypothesis_seed(seed)
    @settings(**common)
    @given(gltf_case())
    def gltf_cases(files):
        model_case("gltf", files)

    @hypothesis_seed(seed)
    @settings(**common)
    @given(obj_case())
    def obj_cases(files):
        model_case("obj", files)

    @hypothesis_seed(seed)
    @settings(**common)
    @given(png_bytes())
    def png_cases(data):
        outcome, detail = run_png(data)
        record("png", outcome, detail, {"t.png": data})

    @hypothesis_seed(seed)
    @settings(**common)
    @given(jpeg_bytes())
    def jpeg_cases(data):
        outcome, detail = run_jpeg(data)
        record("jpeg", outcome, detail, {"t.jpg": data})

    for fn in (gltf_cases, obj_cases, png_cases, jpeg_cases):  # @seed: the same cases for the same seed
        fn()
    return {"cases": {k: dict(v) for k, v in counts.items()}, "failures": failures}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--builds", type=int, default=4, help="cases also run through the real assetpipe build")
    ap.add_argument("--report", type=Path, default=None, help="write counts and failing inputs as JSON")
    ap.add_argument("--address-space", type=int, default=ADDRESS_SPACE)
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    resource.setrlimit(resource.RLIMIT_AS, (args.address_space, args.address_space))
    with tempfile.TemporaryDirectory(prefix="assetpipe-fuzz-") as tmp:
        result = fuzz(args.cases, args.seed, args.builds, Path(tmp))
    total = sum(sum(c.values()) for k, c in result["cases"].items() if k != "build")
    print(f"{total} cases (seed {args.seed}), {sum(result['cases']['build'].values())} builds")
    for kind, c in result["cases"].items():
        print(f"  {kind:6s} " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))
    for f in result["failures"][:20]:
        print(f"FAIL {f['kind']} {f['outcome']}: {f['detail'][:400]}")
    if args.report:
        args.report.write_text(json.dumps(result, indent=1))
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
