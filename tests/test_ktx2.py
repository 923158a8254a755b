"""KTX 2.0 writer/reader: layout per the Khronos spec, round trips, rejection of malformed files,
and a second implementation (ktx-parse, run with node) reading and re-writing our files."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.errors import InvalidTextureError
from assetpipe.core.ktx2 import (KTX2_IDENTIFIER, VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM, read_ktx2,
                            write_ktx2)
from assetpipe.pipelines.texture_mips import build_mip_chain

REPO = Path(__file__).resolve().parents[1]


def chain_levels(w: int, h: int, seed: int = 0, role: str = "baseColor"):
    rgba = np.random.default_rng(seed).integers(0, 256, (h, w, 4), dtype=np.uint8)
    return build_mip_chain(rgba, role).levels


def header(data: bytes) -> dict:
    names = ("vkFormat typeSize pixelWidth pixelHeight pixelDepth layerCount faceCount levelCount "
             "supercompressionScheme dfdByteOffset dfdByteLength kvdByteOffset kvdByteLength "
             "sgdByteOffset sgdByteLength").split()
    return dict(zip(names, struct.unpack_from("<9I4I2Q", data, 12)))


def level_index(data: bytes, n: int) -> list[tuple[int, int, int]]:
    return [struct.unpack_from("<3Q", data, 80 + 24 * k) for k in range(n)]


@pytest.mark.parametrize("w,h", [(300, 17), (211, 211), (1, 7), (1, 1), (16, 16)])
@pytest.mark.parametrize("vk", [VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM])
def test_round_trip_identical(w, h, vk):
    levels = chain_levels(w, h)
    data = write_ktx2(levels, vk)
    img = read_ktx2(data)
    assert (img.vk_format, img.width, img.height) == (vk, w, h)
    assert len(img.levels) == len(levels)
    for a, b in zip(img.levels, levels):
        assert a.dtype == np.uint8 and a.shape == b.shape and (a == b).all()
    assert img.kv == {"KTXorientation": b"rd", "KTXwriter": b"assetpipe"}
    assert img.srgb == (vk == VK_FORMAT_R8G8B8A8_SRGB)
    assert write_ktx2(img.levels, vk) == data  # deterministic


def test_mapped_levels_are_views_of_the_file(tmp_path):
    """``map_file`` + ``copy=False`` (the validator's loader): the same levels as a copying read,
    as read-only views of the mapping (nothing of a level is read until it is used); small files
    are read, not mapped."""
    import mmap

    from assetpipe.core import ktx2 as k

    levels = chain_levels(1024, 512)  # 2.8 MB: over MAP_MIN_BYTES
    data = write_ktx2(levels, VK_FORMAT_R8G8B8A8_SRGB)
    assert len(data) >= k.MAP_MIN_BYTES
    path = tmp_path / "big.ktx2"
    path.write_bytes(data)
    mapped = k.map_file(path)
    assert isinstance(mapped, mmap.mmap)
    img = read_ktx2(mapped, copy=False)
    for a, b in zip(img.levels, read_ktx2(data).levels):
        assert np.array_equal(a, b)
    assert not img.levels[0].flags.writeable and not img.levels[0].flags.owndata
    small = tmp_path / "small.ktx2"
    small.write_bytes(write_ktx2(chain_levels(8, 8), VK_FORMAT_R8G8B8A8_UNORM))
    assert isinstance(k.map_file(small), bytes)
    empty = tmp_path / "empty.ktx2"
    empty.write_bytes(b"")
    assert k.map_file(empty) == b""


def test_header_and_layout_follow_the_spec():
    levels = chain_levels(300, 17)
    data = write_ktx2(levels, VK_FORMAT_R8G8B8A8_SRGB)
    assert data[:12] == KTX2_IDENTIFIER == bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])
    hd = header(data)
    n = len(levels)
    assert hd["vkFormat"] == 43 and hd["typeSize"] == 1
    assert (hd["pixelWidth"], hd["pixelHeight"], hd["pixelDepth"]) == (300, 17, 0)
    assert (hd["layerCount"], hd["faceCount"], hd["levelCount"], hd["supercompressionScheme"]) == (0, 1, n, 0)
    assert hd["dfdByteOffset"] == 80 + 24 * n
    assert hd["kvdByteOffset"] == hd["dfdByteOffset"] + hd["dfdByteLength"]
    assert hd["kvdByteLength"] % 4 == 0
    assert (hd["sgdByteOffset"], hd["sgdByteLength"]) == (0, 0)
    index = level_index(data, n)
    # level 0 first in the index, smallest level first in the file, 4-byte aligned (lcm(4, 4))
    offsets = [off for off, _, _ in index]
    assert offsets == sorted(offsets, reverse=True)
    assert index[-1][0] >= hd["kvdByteOffset"] + hd["kvdByteLength"]
    assert index[-1][0] - (hd["kvdByteOffset"] + hd["kvdByteLength"]) < 4
    for k, (off, length, ulength) in enumerate(index):
        assert off % 4 == 0 and length == ulength == levels[k].nbytes
        assert data[off:off + length] == levels[k].tobytes()
    assert index[0][0] + index[0][1] == len(data)
    # DFD: total size, Khronos basic block v2 of 24 + 4 * 16 bytes
    dfd = data[hd["dfdByteOffset"]:hd["dfdByteOffset"] + hd["dfdByteLength"]]
    total, w0, w1, w2, w3, w4, w5 = struct.unpack_from("<7I", dfd)
    assert total == len(dfd) == 4 + 88
    assert w0 == 0 and w1 == (88 << 16 | 2)
    assert w2 == 1 | 1 << 8 | 2 << 16  # RGBSDA, BT709, sRGB, straight alpha
    assert (w3, w4, w5) == (0, 4, 0)
    samples = [struct.unpack_from("<4I", dfd, 28 + 16 * i) for i in range(4)]
    assert [s[0] & 0xFFFF for s in samples] == [0, 8, 16, 24]
    assert [(s[0] >> 16) & 0xFF for s in samples] == [7] * 4
    assert [s[0] >> 24 for s in samples] == [0, 1, 2, 15 | 0x10]  # alpha linear in an sRGB format
    assert all((s[1], s[2], s[3]) == (0, 0, 255) for s in samples)
    # KVD: sorted keys, NUL-terminated values, each entry padded to 4
    kvd = data[hd["kvdByteOffset"]:hd["kvdByteOffset"] + hd["kvdByteLength"]]
    length = struct.unpack_from("<I", kvd)[0]
    assert kvd[4:4 + length] == b"KTXorientation\x00rd\x00"
    unorm = write_ktx2(levels, VK_FORMAT_R8G8B8A8_UNORM)
    hd_u = header(unorm)
    dfd_u = unorm[hd_u["dfdByteOffset"]:hd_u["dfdByteOffset"] + hd_u["dfdByteLength"]]
    assert struct.unpack_from("<I", dfd_u, 12)[0] == 1 | 1 << 8 | 1 << 16  # linear transfer
    assert struct.unpack_from("<I", dfd_u, 28 + 48)[0] >> 24 == 15


def test_writer_rejects_inconsistent_levels():
    levels = list(chain_levels(8, 8))
    with pytest.raises(ValueError, match='is not supported'):
        write_ktx2(levels, 44)
    with pytest.raises(ValueError, match='no levels'):
        write_ktx2([], 43)
    with pytest.raises(ValueError, match=r"level 1 is .* expected \(4, 4, 4\) uint8"):
        write_ktx2(levels[:1] + levels[2:], 43)
    with pytest.raises(ValueError, match="5 levels for 8x8: at most 4"):
        write_ktx2(levels + [levels[-1]], 43)
    with pytest.raises(ValueError, match=r"level 0 must be \(H, W, 4\) uint8"):
        write_ktx2([levels[0][..., :3].copy()], 43)


def _patch(data: bytes, offset: int, fmt: str, *values) -> bytes:
    b = bytearray(data)
    struct.pack_into(fmt, b, offset, *values)
    return bytes(b)


def test_reader_rejects_every_truncation():
    data = write_ktx2(chain_levels(33, 9), VK_FORMAT_R8G8B8A8_UNORM)
    for cut in list(range(0, 200, 3)) + [len(data) - 1, len(data) - 4, len(data) // 2]:
        with pytest.raises(InvalidTextureError, match="invalid KTX2"):
            read_ktx2(data[:cut], "t.ktx2")
    with pytest.raises(InvalidTextureError, match="unexpected bytes"):
        read_ktx2(data + b"\x00" * 4)


def test_reader_rejects_corrupt_fields():
    levels = chain_levels(32, 8)
    data = write_ktx2(levels, VK_FORMAT_R8G8B8A8_SRGB)
    hd = header(data)
    n = hd["levelCount"]
    dfd, kvd = hd["dfdByteOffset"], hd["kvdByteOffset"]
    bad = {
        "identifier": b"\xabKTX 11\xbb" + data[8:],
        "vkFormat": _patch(data, 12, "<I", 44),
        "typeSize": _patch(data, 16, "<I", 4),
        "zero width": _patch(data, 20, "<I", 0),
        "depth": _patch(data, 28, "<I", 1),
        "layers": _patch(data, 32, "<I", 2),
        "faces": _patch(data, 36, "<I", 6),
        "too many levels": _patch(data, 40, "<I", 9),
        "supercompression": _patch(data, 44, "<I", 2),
        "dfd offset": _patch(data, 48, "<I", dfd + 4),
        "dfd length": _patch(data, 52, "<I", 10_000),
        "sgd": _patch(data, 64, "<QQ", 8, 8),
        "dfd total": _patch(data, dfd, "<I", 0),
        "dfd transfer": _patch(data, dfd + 12, "<I", 1 | 1 << 8 | 1 << 16),
        "dfd model": _patch(data, dfd + 12, "<I", 2 | 1 << 8 | 2 << 16),
        "dfd bytesPlane": _patch(data, dfd + 20, "<I", 3),
        "dfd sample": _patch(data, dfd + 28, "<I", 0 | 15 << 16),
        "dfd block size": _patch(data, dfd + 8, "<I", 2 | 72 << 16),
        "kvd entry overrun": _patch(data, kvd, "<I", 10_000),
        "kvd no key": _patch(data, kvd + 4, "<B", 0),
        "level length": _patch(data, 80 + 8, "<Q", levels[0].nbytes - 4),
        "level uncompressed": _patch(data, 80 + 16, "<Q", 1),
        "level misaligned": _patch(data, 80, "<Q", level_index(data, n)[0][0] + 2),
        "level outside": _patch(data, 80, "<Q", len(data)),
        "levels overlap": _patch(data, 80 + 24, "<Q", level_index(data, n)[0][0]),
        "levels largest first": _patch(_patch(data, 80 + 24 * (n - 1), "<Q", level_index(data, n)[0][0]),
                                       80, "<Q", level_index(data, n)[n - 1][0]),
    }
    for what, blob in bad.items():
        with pytest.raises(InvalidTextureError, match="t.ktx2: invalid KTX2 file"):
            read_ktx2(blob, "t.ktx2")
            pytest.fail(f"accepted a file with a bad {what}")


def test_reader_rejects_unsorted_keys():
    levels = chain_levels(4, 4)
    data = write_ktx2(levels, VK_FORMAT_R8G8B8A8_SRGB, kv={"AAA": b"1\x00"})
    assert read_ktx2(data).kv["AAA"] == b"1\x00"  # non-KTX values are kept as written
    hd = header(data)
    kvd = bytearray(data[hd["kvdByteOffset"]:hd["kvdByteOffset"] + hd["kvdByteLength"]])
    kvd[4:7] = b"ZZZ"  # first key now sorts after KTXorientation
    patched = data[:hd["kvdByteOffset"]] + bytes(kvd) + data[hd["kvdByteOffset"] + hd["kvdByteLength"]:]
    with pytest.raises(InvalidTextureError, match="not sorted"):
        read_ktx2(patched)


def test_random_corruption_never_escapes_as_another_exception():
    data = write_ktx2(chain_levels(20, 12), VK_FORMAT_R8G8B8A8_SRGB)
    rng = np.random.default_rng(1)
    rejected = 0
    for _ in range(400):
        b = bytearray(data)
        for pos in rng.integers(0, 300, size=3):
            b[pos] = int(rng.integers(0, 256))
        try:
            read_ktx2(bytes(b))
        except InvalidTextureError:
            rejected += 1
    assert rejected > 200


# ----------------------------------------------------------------------------- a second implementation

def _ktx_parse_dir() -> Path | None:
    """ktx-parse (npm) installed by: npm install --prefix .venv/node ktx-parse@2.0.0"""
    candidates = []
    if os.environ.get("ASSETPIPE_KTX_PARSE"):
        candidates.append(Path(os.environ["ASSETPIPE_KTX_PARSE"]))
    candidates.append(REPO / ".venv" / "node" / "node_modules" / "ktx-parse")
    # the virtual environment running the tests (setup.sh puts the node tools in it), wherever it is
    candidates.append(Path(sys.prefix) / "node" / "node_modules" / "ktx-parse")
    npm = shutil.which("npm")
    if npm:
        try:
            root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True, timeout=30).stdout.strip()
            if root:
                candidates.append(Path(root) / "ktx-parse")
        except (OSError, subprocess.SubprocessError):
            pass
    for c in candidates:
        if (c / "package.json").is_file():
            return c
    return None


_NODE_SCRIPT = r"""
import { read, write } from %(module)s;
import { readFileSync, writeFileSync } from 'fs';
const [mode, path, outPath] = process.argv.slice(2);
const src = new Uint8Array(readFileSync(path));
if (mode === 'inspect') {
  const c = read(src);
  const d = c.dataFormatDescriptor[0];
  const again = write(c, { keepWriter: true });
  const identical = again.length === src.length && again.every((v, i) => v === src[i]);
  console.log(JSON.stringify({
    vkFormat: c.vkFormat, typeSize: c.typeSize, pixelWidth: c.pixelWidth, pixelHeight: c.pixelHeight,
    pixelDepth: c.pixelDepth, layerCount: c.layerCount, faceCount: c.faceCount, levelCount: c.levelCount,
    supercompressionScheme: c.supercompressionScheme, keyValue: c.keyValue,
    dfd: { colorModel: d.colorModel, colorPrimaries: d.colorPrimaries, transferFunction: d.transferFunction,
           flags: d.flags, bytesPlane: d.bytesPlane, samples: d.samples },
    levels: c.levels.map(l => ({ n: l.levelData.byteLength, u: l.uncompressedByteLength,
                                 sum: l.levelData.reduce((a, b) => (a + b) %% 1000000007, 0) })),
    rewrittenIdentical: identical }));
} else {
  // Build a file with ktx-parse's own writer from our levels (ktx-parse's KTXwriter value).
  const c = read(src);
  c.keyValue = { KTXorientation: 'rd' };
  writeFileSync(outPath, write(c));
}
"""


@pytest.fixture(scope="module")
def ktx_parse(tmp_path_factory):
    node = shutil.which("node")
    pkg = _ktx_parse_dir()
    if node is None or pkg is None:
        pytest.fail("needs node and the npm package ktx-parse (scripts/setup.sh installs them: "
                    "npm install --prefix .venv/node ktx-parse@2.0.0)")
    script = tmp_path_factory.mktemp("ktxparse") / "check.mjs"
    module = json.dumps((pkg / "dist" / "index.mjs").as_uri())
    script.write_text(_NODE_SCRIPT % {"module": module})

    def run(*args: str) -> str:
        res = subprocess.run([node, str(script), *args], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
        return res.stdout

    return run


@pytest.mark.parametrize("w,h,vk,role", [(300, 17, 43, "baseColor"), (211, 211, 37, "normal"), (1, 7, 43, "emissive")])
def test_ktx_parse_reads_our_files(ktx_parse, tmp_path, w, h, vk, role):
    levels = chain_levels(w, h, role=role)
    path = tmp_path / "t.ktx2"
    path.write_bytes(write_ktx2(levels, vk))
    got = json.loads(ktx_parse("inspect", str(path)))
    assert got["vkFormat"] == vk and got["typeSize"] == 1
    assert (got["pixelWidth"], got["pixelHeight"], got["pixelDepth"]) == (w, h, 0)
    assert (got["layerCount"], got["faceCount"], got["levelCount"], got["supercompressionScheme"]) == (0, 1, len(levels), 0)
    assert got["keyValue"] == {"KTXorientation": "rd", "KTXwriter": "assetpipe"}
    dfd = got["dfd"]
    assert (dfd["colorModel"], dfd["colorPrimaries"], dfd["flags"]) == (1, 1, 0)
    assert dfd["transferFunction"] == (2 if vk == 43 else 1)
    assert dfd["bytesPlane"] == [4, 0, 0, 0, 0, 0, 0, 0]
    assert [s["channelType"] for s in dfd["samples"]] == [0, 1, 2, 31 if vk == 43 else 15]
    assert all(s["bitLength"] == 7 and s["sampleUpper"] == 255 for s in dfd["samples"])
    for lv, theirs in zip(levels, got["levels"]):
        assert theirs["n"] == theirs["u"] == lv.nbytes
        assert theirs["sum"] == int(lv.astype(np.int64).sum()) % 1000000007
    # ktx-parse writes our container back byte for byte: same layout, padding and ordering
    assert got["rewrittenIdentical"]


def test_we_read_ktx_parse_written_files(ktx_parse, tmp_path):
    levels = chain_levels(45, 30, seed=3)
    ours = tmp_path / "ours.ktx2"
    ours.write_bytes(write_ktx2(levels, VK_FORMAT_R8G8B8A8_SRGB))
    theirs = tmp_path / "theirs.ktx2"
    ktx_parse("rewrite", str(ours), str(theirs))
    img = read_ktx2(theirs.read_bytes(), str(theirs))
    assert img.kv["KTXwriter"].startswith(b"KTX-Parse")
    assert all((a == b).all() for a, b in zip(img.levels, levels))
