"""Decoding every pixel layout we accept into RGBA, and refusing what we must refuse."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from assetpipe.core.errors import InvalidTextureError
from assetpipe.core.hashing import digest_bytes
from assetpipe.pipelines.image_source import sniff_mime
from assetpipe.pipelines.model import ImageSource
from assetpipe.pipelines.texture_decode import decode_image, has_alpha_below_255


def source(data: bytes, name: str = "t.png", mime: str | None = None) -> ImageSource:
    mime = mime or sniff_mime(data) or "image/x-tga"
    return ImageSource(name=name, data=data, mime=mime, origin=f"/models/{name}", digest=digest_bytes(data))


def pil_bytes(im: Image.Image, fmt: str, **kw) -> bytes:
    buf = io.BytesIO()
    im.save(buf, fmt, **kw)
    return buf.getvalue()


def raw_png(width: int, height: int, depth: int, colour_type: int, raw_rows: bytes) -> bytes:
    """A minimal PNG (filter 0 rows), for layouts neither Pillow nor OpenCV write."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw_rows)) + chunk(b"IEND", b"")


RGB = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]],
                [[10, 20, 30], [40, 50, 60], [70, 80, 90]]], dtype=np.uint8)  # 2 x 3


def test_rgb_png():
    out = decode_image(source(pil_bytes(Image.fromarray(RGB), "PNG")))
    assert out.shape == (2, 3, 4) and out.dtype == np.uint8 and out.flags.c_contiguous
    assert (out[..., :3] == RGB).all() and (out[..., 3] == 255).all()
    assert not has_alpha_below_255(out)


def test_rgba_png():
    rgba = np.dstack([RGB, np.array([[0, 128, 255], [1, 2, 3]], np.uint8)])
    out = decode_image(source(pil_bytes(Image.fromarray(rgba, "RGBA"), "PNG")))
    assert (out == rgba).all()
    assert has_alpha_below_255(out)


def test_palette_png_with_transparency():
    im = Image.fromarray(RGB).convert("P", palette=Image.Palette.ADAPTIVE, colors=8)
    idx = np.asarray(im)
    data = pil_bytes(im, "PNG", transparency=int(idx[0, 0]))
    out = decode_image(source(data))
    assert out[0, 0, 3] == 0
    assert (out[..., 3][idx != idx[0, 0]] == 255).all()
    assert (out[1, 1, :3] == RGB[1, 1]).all()


def test_palette_png_without_transparency():
    im = Image.fromarray(RGB).convert("P", palette=Image.Palette.ADAPTIVE, colors=8)
    out = decode_image(source(pil_bytes(im, "PNG")))
    assert (out[..., :3] == RGB).all() and (out[..., 3] == 255).all()


def test_grey_and_grey_alpha_png():
    grey = np.array([[0, 100], [200, 255]], np.uint8)
    out = decode_image(source(pil_bytes(Image.fromarray(grey, "L"), "PNG")))
    assert (out[..., 0] == grey).all() and (out[..., 2] == grey).all() and (out[..., 3] == 255).all()
    la = Image.fromarray(np.dstack([grey, 255 - grey]), "LA")
    out = decode_image(source(pil_bytes(la, "PNG")))
    assert (out[..., 1] == grey).all() and (out[..., 3] == 255 - grey).all()
    # grey with a colour key
    out = decode_image(source(pil_bytes(Image.fromarray(grey, "L"), "PNG", transparency=100)))
    assert out[0, 1, 3] == 0 and out[0, 0, 3] == 255


def test_16bit_pngs_keep_16_bits():
    rgba16 = (np.arange(2 * 3 * 4, dtype=np.uint16).reshape(2, 3, 4) * 2731 + 7)
    ok, buf = cv2.imencode(".png", rgba16[..., [2, 1, 0, 3]])
    out = decode_image(source(buf.tobytes()))
    assert out.dtype == np.uint16 and (out == rgba16).all()
    ok, buf = cv2.imencode(".png", rgba16[..., [2, 1, 0]])  # RGB 16
    out = decode_image(source(buf.tobytes()))
    assert (out[..., :3] == rgba16[..., :3]).all() and (out[..., 3] == 65535).all()
    ok, buf = cv2.imencode(".png", rgba16[..., 0])  # grey 16
    out = decode_image(source(buf.tobytes()))
    assert (out[..., 1] == rgba16[..., 0]).all() and (out[..., 3] == 65535).all()
    assert not has_alpha_below_255(out)


def test_16bit_grey_alpha_png():
    g = np.array([[1000, 60000]], dtype=np.uint16)
    a = np.array([[65535, 5]], dtype=np.uint16)
    rows = b"\x00" + np.dstack([g, a]).astype(">u2").tobytes()  # PNG samples are big-endian
    out = decode_image(source(raw_png(2, 1, 16, 4, rows)))
    assert out.dtype == np.uint16
    assert out[0, 0].tolist() == [1000, 1000, 1000, 65535]
    assert out[0, 1].tolist() == [60000, 60000, 60000, 5]
    assert has_alpha_below_255(out)


def test_jpeg_tga_bmp():
    smooth = np.full((8, 8, 3), (200, 100, 50), np.uint8)
    out = decode_image(source(pil_bytes(Image.fromarray(smooth), "JPEG", quality=95)))
    assert np.abs(out[..., :3].astype(int) - smooth).max() <= 3 and (out[..., 3] == 255).all()
    rgba = np.dstack([RGB, np.full((2, 3), 77, np.uint8)])
    out = decode_image(source(pil_bytes(Image.fromarray(rgba, "RGBA"), "TGA"), "t.tga", "image/x-tga"))
    assert (out == rgba).all()
    out = decode_image(source(pil_bytes(Image.fromarray(RGB), "BMP"), "t.bmp"))
    assert (out[..., :3] == RGB).all()


def test_exif_orientation_is_ignored():
    tall = np.zeros((16, 8, 3), np.uint8)
    tall[:8] = 255  # top half white
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to display"
    data = pil_bytes(Image.fromarray(tall), "JPEG", quality=95, exif=exif.tobytes())
    assert Image.open(io.BytesIO(data)).getexif().get(0x0112) == 6
    out = decode_image(source(data))
    assert out.shape == (16, 8, 4)  # stored rows, not rotated
    assert out[:6, :, 0].min() > 200 and out[10:, :, 0].max() < 50


def test_decompression_bomb_is_refused_from_the_header():
    # IHDR says 100000 x 100000; no pixel data needed to refuse it.
    data = raw_png(100000, 100000, 8, 6, b"")
    with pytest.raises(InvalidTextureError, match="over the limit"):
        decode_image(source(data))
    small = pil_bytes(Image.fromarray(RGB), "PNG")
    with pytest.raises(InvalidTextureError, match="3x2 = 6 pixels, 24 bytes decoded as RGBA: over the limit of 5 RGBA8 texels"):
        decode_image(source(small), max_pixels=5)
    jpeg = pil_bytes(Image.fromarray(RGB), "JPEG")
    with pytest.raises(InvalidTextureError, match="over the limit"):
        decode_image(source(jpeg), max_pixels=5)


def test_bomb_above_pillows_own_limit_is_ours_not_a_warning():
    # 20000 x 20000 exceeds Pillow's MAX_IMAGE_PIXELS warning threshold; a GIF header is enough.
    data = b"GIF89a" + struct.pack("<HH", 20000, 20000) + b"\x00\x00\x00" + b"," + b"\x00" * 9
    with _no_warning():
        with pytest.raises(InvalidTextureError, match='cannot identify image file'):
            decode_image(source(data, "bomb.gif"), max_pixels=10_000)


class _no_warning:
    def __enter__(self):
        import warnings
        self._cm = warnings.catch_warnings(record=True)
        self.records = self._cm.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        self._cm.__exit__(*exc)
        assert not [r for r in self.records if issubclass(r.category, Image.DecompressionBombWarning)]
        return False


@pytest.mark.parametrize("cut", [40, 100, 300])
def test_truncated_and_corrupt(cut):
    rng = np.random.default_rng(0)
    noisy = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    data = pil_bytes(Image.fromarray(noisy), "PNG")
    with pytest.raises(InvalidTextureError, match="/models/t.png"):
        decode_image(source(data[:cut]))
    jpeg = pil_bytes(Image.fromarray(noisy), "JPEG")
    with pytest.raises(InvalidTextureError, match="jpg' cannot be decoded"):
        decode_image(source(jpeg[:cut], "t.jpg"))


def test_garbage_and_unsupported():
    with pytest.raises(InvalidTextureError, match='cannot identify image file'):
        decode_image(source(b"not an image at all", "x.tga", "image/x-tga"))
    tiff = pil_bytes(Image.fromarray(RGB), "TIFF")
    with pytest.raises(InvalidTextureError, match="tif' is a TIFF image, not a supported format"):
        decode_image(source(tiff, "x.tif", "image/tiff"))
    corrupt16 = raw_png(4, 4, 16, 2, b"\x00" * 3)
    with pytest.raises(InvalidTextureError, match="png' is a corrupt or truncated PNG"):
        decode_image(source(corrupt16))


def test_corpus_layouts_decode(corpus):
    models = corpus / "models"
    cases = {
        "BoxTexturedNonPowerOfTwo/glTF/CesiumLogoFlat.png": (211, 211),  # palette
        "Duck/glTF/DuckCM.png": (512, 512),                                # palette
        "BoxTextured/glTF/CesiumLogoFlat.png": (256, 256),                 # RGBA
        "TextureTransformTest/glTF/Correct.png": (128, 128),               # RGB
        "spider/SpiderTex.jpg": (250, 249),                                # JPEG, odd size
    }
    for rel, (h, w) in cases.items():
        data = (models / rel).read_bytes()
        out = decode_image(source(data, rel))
        assert out.shape == (h, w, 4) and out.dtype == np.uint8
        ref = np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))
        assert (out == ref).all()


# -- hostile images (#13) ------------------------------------------------------------------------

def _zero_png(width: int, height: int, depth: int) -> bytes:
    """An RGBA PNG of zero rows compressed as one stream: megapixels in a few KB."""
    row = b"\x00" * (1 + width * 4 * depth // 8)
    co = zlib.compressobj(9)
    body = b"".join(co.compress(row) for _ in range(height)) + co.flush()
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, depth, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b"")


def test_16bit_png_counts_twice_the_bytes_and_is_refused_before_opencv_decodes_it():
    # 16384 x 16384 RGBA16 from a 2 MB file used to decode on the OpenCV path (4.1 GB peak):
    # 2 GiB decoded is over the default 1 GiB (16384^2 RGBA8 texels), refused from the header.
    # Here the same rule at a small scale: 64x64 RGBA16 = 32 KiB against a limit of 4096 texels
    # (16 KiB), while the 8-bit image of the same size (16 KiB) passes.
    with pytest.raises(InvalidTextureError, match=r"64x64 16-bit = 4096 pixels, 32768 bytes decoded as RGBA: over the limit of 4096"):
        decode_image(source(_zero_png(64, 64, 16)), max_pixels=64 * 64)
    assert decode_image(source(_zero_png(64, 64, 8)), max_pixels=64 * 64).shape == (64, 64, 4)
    assert decode_image(source(_zero_png(32, 64, 16)), max_pixels=64 * 64).dtype == np.uint16


def test_a_16bit_bomb_header_is_refused_without_decoding():
    data = raw_png(16384, 16384, 16, 6, b"")  # header only: decoding would fail, refusing must not decode
    with pytest.raises(InvalidTextureError, match=r"16384x16384 16-bit = 268435456 pixels, 2048\.0 MiB decoded"):
        decode_image(source(data))


def test_pillows_bomb_limit_never_refuses_what_ours_accepts(monkeypatch):
    # A real 16384^2 PNG is within our limit but over Pillow's (2 x 89 M pixels): it was dropped
    # as "too large". Lower Pillow's limit far below a small image to show it no longer applies.
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    data = pil_bytes(Image.new("RGBA", (64, 64), (1, 2, 3, 4)), "PNG")
    assert decode_image(source(data)).shape == (64, 64, 4)
    assert Image.MAX_IMAGE_PIXELS == 100  # restored after use


def test_a_corrupt_16bit_png_is_one_line_with_nothing_on_stderr(capfd):
    # libpng (through OpenCV) printed "libpng error: IDAT: incorrect data check" and the like to
    # stderr: extra lines beside the one-line error. The stream is checked before OpenCV sees it.
    good = _zero_png(8, 8, 16)
    assert decode_image(source(good)).shape == (8, 8, 4)
    idat = good.index(b"IDAT")
    broken = bytearray(good)
    broken[idat + 6] ^= 0xFF  # inside the zlib stream: the CRC no longer matches
    truncated = raw_png(8, 8, 16, 6, bytes(1 + 8 * 8)[:20])  # valid CRCs, too little pixel data
    for data, words in ((bytes(broken), "corrupt b'IDAT' chunk"), (truncated, "corrupt or truncated PNG")):
        with pytest.raises(InvalidTextureError, match=words):
            decode_image(source(data))
    assert capfd.readouterr().err == ""


# -- found by mutating corpus JPEGs (stop 28) ------------------------------------------------------

DATA = Path(__file__).resolve().parent / "data" / "images"


def test_every_format_hint_names_one_of_pillows_openers():
    # a name Pillow has no opener for ("MPO" in Pillow 13: such files open through "JPEG") made
    # every JPEG that failed to open a KeyError instead of an InvalidTextureError
    from PIL import Image

    from assetpipe.pipelines.texture_decode import _PIL_FORMAT_HINT

    Image.init()
    assert [n for names in _PIL_FORMAT_HINT.values() for n in names if n not in Image.OPEN] == []


def test_a_jpeg_that_does_not_open_is_an_invalid_texture():
    src = ImageSource(name="t", data=b"\xff\xd8\xff\xe0" + bytes(20), mime="image/jpeg", origin="t.jpg", digest="x")
    with pytest.raises(InvalidTextureError, match="t.jpg.*cannot be decoded"):
        decode_image(src)


def test_pillows_complaints_about_metadata_stay_out_of_the_output():
    # tests/data/images/exif-cut-short.jpg: a 16x16 JPEG whose EXIF block was cut short by two
    # changed bytes; the pixels decode, and Pillow warned "Truncated File Read" (a stray line)
    import warnings

    data = (DATA / "exif-cut-short.jpg").read_bytes()
    src = ImageSource(name="t", data=data, mime="image/jpeg", origin="t.jpg", digest="x")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        rgba = decode_image(src)
    assert rgba.shape == (16, 16, 4) and seen == []


def test_a_small_png_claiming_a_large_image_is_refused_before_its_pixels_are_allocated():
    """Within max_pixels, but its stream holds 64 of 4096 rows: the stream is inflated first
    and the missing pixel data refused, with no image allocated (a 4096^2 RGBA header over a
    file of about 1 KiB claims 64 MiB)."""
    import tracemalloc

    data = raw_png(4096, 4096, 8, 6, bytes(64 * (1 + 4096 * 4)))
    tracemalloc.start()
    try:
        with pytest.raises(InvalidTextureError, match="corrupt or truncated PNG .its pixel data holds"):
            decode_image(source(data))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20, peak


def test_an_8bit_png_whose_stream_does_not_inflate_is_not_called_16bit():
    """A zlib error in the pixel stream (chunk CRCs valid) names the problem without calling an
    8-bit PNG a 16-bit one (the message said "16-bit" for every PNG before)."""
    good = raw_png(8, 8, 8, 2, bytes(8 * (1 + 8 * 3)))
    at = good.index(b"IDAT") + 4
    body = b"\x78\x9c\xff\xff\xff\xff" + b"\x00" * 8
    length = struct.unpack(">I", good[at - 8:at - 4])[0]
    bad = (good[:at - 8] + struct.pack(">I", len(body)) + b"IDAT" + body
           + struct.pack(">I", zlib.crc32(b"IDAT" + body)) + good[at + length + 4:])
    with pytest.raises(InvalidTextureError, match=r"t.png' is a corrupt PNG \(") as err:
        decode_image(source(bad))
    assert "16-bit" not in str(err.value)


@pytest.mark.parametrize("mode", ["RGB", "L"])
@pytest.mark.parametrize("key", [None, 7])
def test_rgb_and_grey_widen_to_rgba_exactly_as_pillow_converts(mode, key):
    """RGB and grey bands are widened by OpenCV (a third of Pillow's time): the same bytes as
    Pillow's convert("RGBA"), across band edges; a colour key still goes through Pillow."""
    from PIL import Image

    from assetpipe.pipelines import texture_decode

    rng = np.random.default_rng(3)
    rows = texture_decode._BAND_BYTES // (4 * 333) * 2 + 5  # three bands, the last one short
    a = rng.integers(0, 256, (rows, 333) + ((3,) if mode == "RGB" else ()), dtype=np.uint8)
    im = Image.fromarray(a, mode)
    if key is not None:
        im.info["transparency"] = key if mode == "L" else (key, key, key)
        a.reshape(-1)[:30] = key  # some texels on the key
        im = Image.fromarray(a, mode)
        im.info["transparency"] = key if mode == "L" else (key, key, key)
    got = texture_decode._to_rgba(im)
    assert got.dtype == np.uint8 and got.flags.c_contiguous
    assert np.array_equal(got, np.asarray(im.convert("RGBA")))
    if key is not None:
        assert (got[..., 3] == 0).any()  # the key made some texels transparent


def test_a_small_png_whose_stream_ends_cleanly_but_short_is_refused():
    """A complete zlib stream holding 8 of the 64 rows its header claims: Pillow would decode it
    without a word (the missing rows black), so the stream is inflated and measured first, for a
    small image too (not only for a claim a file could not back)."""
    data = raw_png(64, 64, 8, 6, bytes(8 * (1 + 64 * 4)))
    with pytest.raises(InvalidTextureError, match=r"corrupt or truncated PNG \(its pixel data holds 2056 of 16448 bytes\)"):
        decode_image(source(data))
