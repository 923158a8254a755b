"""The texture step the build calls: encoded image -> KTX2 mip chain + level-0 image.

Pure: bytes in, bytes out. The build writes ``level0`` to ``textures/<digest><level0_ext>``
(when ``level0_shared``; see below) and ``ktx2`` to ``textures/<digest>-<role>.ktx2``, and
copies ``width``, ``height``, ``levels``, ``vk_format`` and ``srgb`` (``colorSpace``) into the
sidecar.

With ``options.compression`` ``"bc"`` or ``"etc2"`` the KTX2 holds block-compressed levels
(:mod:`assetpipe.pipelines.texture_compress`), each compressed from the chain's own level after
``max_size`` dropped any top levels (nothing is compressed that is not kept); the level-0
PNG/JPEG for ``texturePath`` is unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from assetpipe.core.errors import InvalidTextureError
from assetpipe.core.ktx2 import (SUPERCOMPRESSION_NONE, SUPERCOMPRESSION_ZSTD, VK_FORMAT_R8G8B8A8_SRGB,
                                 VK_FORMAT_R8G8B8A8_UNORM, write_ktx2)
from assetpipe.pipelines.model import ROLE_METALLIC_ROUGHNESS, ROLE_OCCLUSION, ImageSource
from assetpipe.pipelines.texture_decode import decode_image, has_alpha_below_255, image_size
from assetpipe.pipelines.texture_mips import build_mip_chain
from assetpipe.pipelines.texture_options import DEFAULT_TEXTURE_OPTIONS, TextureOptions

# When the output of process_texture changes for the same input and options (filtering,
# KTX2 layout, level-0 encoding), bump assetpipe/versions.py's TEXTURE: the step's cache key.

_KEEP_AS_IS = {"image/png": ".png", "image/jpeg": ".jpg"}


@dataclass(frozen=True, eq=False)
class ProcessedTexture:
    """The result of :func:`process_texture`.

    ``ktx2``: the KTX 2.0 file, full mip chain, level 0 = ``width`` x ``height``.
    ``level0``: an encoded image of level 0 for ``texturePath`` (stb_image loads it): the
    source bytes unchanged when the source is PNG or JPEG and no level was dropped for
    ``max_size``; else a PNG (RGB when opaque, RGBA otherwise) that we encode.
    ``level0_ext``: ``".png"`` or ``".jpg"``.
    ``level0_shared``: ``level0`` depends only on the image (and options), not on the role,
    alpha mode or cutoff, so it can be named by the image digest alone. False when levels were
    dropped for ``max_size``: the reduced level 0 was filtered as the role requires (name it
    per role then).
    ``mean_drift``: per KTX2 level, max over channels of ``|mean(level k) - mean(level 0)|``
    in linear light, 1/255 units (see :class:`pipelines.texture_mips.MipChain`); a cheap
    energy-conservation figure (filtering itself is an exact area average, checked in the
    tests against a float64 reference at <= 0.5 mean absolute error per level).
    ``coverage``: per level, alpha-test coverage for baseColor with alphaMode MASK, else None.
    ``warnings``: one line when levels were dropped for ``max_size`` (the image, its size, the
    size built), else empty.
    """

    ktx2: bytes
    level0: bytes
    level0_ext: str
    level0_shared: bool
    width: int
    height: int
    levels: int
    vk_format: int
    srgb: bool
    has_alpha_below_255: bool
    alpha_weighted: bool
    mean_drift: tuple[float, ...]
    coverage: tuple[float, ...] | None
    source_width: int
    source_height: int
    warnings: tuple[str, ...] = ()

    @property
    def color_space(self) -> str:
        """The sidecar's ``colorSpace``: ``"srgb"`` or ``"linear"``."""
        return "srgb" if self.srgb else "linear"


def encode_png(rgba: np.ndarray) -> bytes:
    """PNG bytes of ``(H, W, 4)`` uint8 RGBA (written as RGB when every alpha is 255)."""
    if rgba.dtype != np.uint8:
        raise ValueError("encode_png takes uint8 RGBA")
    if has_alpha_below_255(rgba):
        bgr = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)
    else:
        bgr = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR)
    ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


#: roles filtered alike (every channel linear, alpha too): one chain serves them all, the same
#: KTX2 bytes (an ORM image used for occlusion and for metallicRoughness is filtered once). Of
#: the alpha modes only MASK (with its cutoff) changes a chain: OPAQUE and BLEND filter alike
#: (:func:`pipelines.texture_mips.build_mip_chain`).
_LINEAR_ROLES = (ROLE_METALLIC_ROUGHNESS, ROLE_OCCLUSION)

#: one use of an image: (role, alphaMode, alphaCutoff)
TextureUse = tuple[str, str, float]


def process_texture(image: ImageSource, role: str, alpha_mode: str = "OPAQUE", alpha_cutoff: float = 0.5,
                    options: TextureOptions = DEFAULT_TEXTURE_OPTIONS) -> ProcessedTexture:
    """Decode ``image``, build its mip chain for ``role`` and encode KTX2 + level 0.

    Raises :class:`InvalidTextureError` for undecodable or too large images, and, with
    ``options.oversize == "refuse"``, for an image larger than ``options.max_size`` (read from
    its header, before decoding).
    """
    return process_texture_uses(image, [(role, alpha_mode, alpha_cutoff)], options)[0]


def process_texture_uses(image: ImageSource, uses: Sequence[TextureUse],
                         options: TextureOptions = DEFAULT_TEXTURE_OPTIONS) -> list[ProcessedTexture]:
    """:func:`process_texture` for every use of one image (a model's materials may sample it as
    several roles, or as baseColor with several alpha modes): the image is decoded once, and
    uses filtered alike (:data:`_LINEAR_ROLES`; OPAQUE and BLEND) share one chain. Element ``i``
    of the result is exactly ``process_texture(image, *uses[i], options)``."""
    if options.oversize == "refuse" and options.max_size is not None:
        size = image_size(image)
        if size is not None and max(size) > options.max_size:
            raise InvalidTextureError(
                image.origin or image.name,
                f"image {image.name!r} is {size[0]}x{size[1]}: larger than the maximum texture size {options.max_size} "
                "(refused: oversize textures are set to refuse; --max-texture-size raises the limit)")
    rgba = decode_image(image, max_pixels=options.max_pixels)
    alpha_below = has_alpha_below_255(rgba)
    done: dict[tuple, ProcessedTexture] = {}
    out = []
    for role, alpha_mode, alpha_cutoff in uses:
        same = ("linear",) if role in _LINEAR_ROLES else (role, float(alpha_cutoff) if alpha_mode == "MASK" else None)
        if same not in done:
            done[same] = _process_decoded(image, rgba, alpha_below, role, alpha_mode, alpha_cutoff, options)
        out.append(done[same])
    return out


def _process_decoded(image: ImageSource, rgba: np.ndarray, alpha_below: bool, role: str, alpha_mode: str,
                     alpha_cutoff: float, options: TextureOptions) -> ProcessedTexture:
    """One use of a decoded image (``rgba`` as :func:`decode_image` returns it; not modified)."""
    source_h, source_w = rgba.shape[:2]
    chain = build_mip_chain(rgba, role, alpha_mode, alpha_cutoff, options)
    scheme = SUPERCOMPRESSION_ZSTD if options.supercompression == "zstd" else SUPERCOMPRESSION_NONE
    try:
        if options.compression == "none":
            vk_format = VK_FORMAT_R8G8B8A8_SRGB if chain.srgb else VK_FORMAT_R8G8B8A8_UNORM
            ktx2 = write_ktx2(chain.levels, vk_format, supercompression=scheme, zstd_level=options.zstd_level)
        else:
            from assetpipe.pipelines.texture_compress import choose_format, compress_chain  # noqa: PLC0415

            has_alpha = any(has_alpha_below_255(lv) for lv in chain.levels)
            fmt = choose_format(options.compression, role, chain.srgb, has_alpha)
            blocks = compress_chain(chain.levels, fmt)
            vk_format = fmt.vk_format
            ktx2 = write_ktx2(blocks.levels, vk_format, width=chain.width, height=chain.height,
                              supercompression=scheme, zstd_level=options.zstd_level)
    except ValueError as exc:  # pragma: no cover - the chain is built to fit
        raise InvalidTextureError(image.origin, f"cannot write KTX2: {exc}") from None

    warnings: tuple[str, ...] = ()
    if chain.dropped_levels:
        level0, ext, shared = encode_png(chain.levels[0]), ".png", False
        warnings = (f"{image.origin or image.name}: image {image.name!r} is {source_w}x{source_h}, larger than the "
                    f"maximum texture size {options.max_size}: built at {chain.width}x{chain.height} "
                    f"({chain.dropped_levels} top mip level(s) dropped; --max-texture-size 0 keeps the full size, "
                    "--oversize-textures refuse refuses such images)",)
    elif image.mime in _KEEP_AS_IS:
        level0, ext, shared = image.data, _KEEP_AS_IS[image.mime], True
    else:  # TGA, BMP, GIF, WebP: stb_image-friendly PNG of the decoded source
        src8 = rgba if rgba.dtype == np.uint8 else cv2.convertScaleAbs(rgba, alpha=1.0 / 257.0)
        level0, ext, shared = encode_png(src8), ".png", True

    return ProcessedTexture(
        ktx2=ktx2, level0=level0, level0_ext=ext, level0_shared=shared,
        width=chain.width, height=chain.height, levels=len(chain.levels), vk_format=vk_format,
        srgb=chain.srgb, has_alpha_below_255=alpha_below, alpha_weighted=chain.alpha_weighted,
        mean_drift=chain.mean_drift, coverage=chain.coverage,
        source_width=source_w, source_height=source_h, warnings=warnings)
