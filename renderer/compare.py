"""Image comparisons used by the checks and the goldens (numpy only, no per-pixel loops)."""

from __future__ import annotations

import numpy as np


def coverage(img: np.ndarray) -> np.ndarray:
    """Covered pixels of an RGBA render (alpha > 0: the background is cleared to alpha 0)."""
    return img[..., 3] > 0


def front(img: np.ndarray) -> np.ndarray:
    """Pixels of a ``mode="facing"`` render where the nearest surface faces the camera (or is
    double-sided): red 255 there, about 188 (0.5 encoded as sRGB) where a back face is nearest."""
    return (img[..., 3] > 0) & (img[..., 0] > 220)


def bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) of ``mask``, x1/y1 exclusive, or None when empty."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return None
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def dilate(mask: np.ndarray, radius: int = 1) -> np.ndarray:
    """Square (Chebyshev) dilation of a boolean mask by ``radius`` pixels."""
    out = mask.copy()
    for _ in range(radius):
        grown = out.copy()
        grown[1:, :] |= out[:-1, :]
        grown[:-1, :] |= out[1:, :]
        g2 = grown.copy()
        g2[:, 1:] |= grown[:, :-1]
        g2[:, :-1] |= grown[:, 1:]
        out = g2
    return out


def unexplained(a: np.ndarray, b: np.ndarray, radius: int = 1) -> np.ndarray:
    """Pixels where the silhouettes differ by more than ``radius`` px.

    A pixel of ``a`` not within ``radius`` of ``b`` (or the reverse) cannot be explained by
    an edge moving at most ``radius`` pixels.
    """
    return (a & ~dilate(b, radius)) | (b & ~dilate(a, radius))


def xor_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Differing pixels over the union of both silhouettes (0 when both are empty)."""
    union = int((a | b).sum())
    return float((a ^ b).sum()) / union if union else 0.0


def block_color_difference(img_a: np.ndarray, img_b: np.ndarray, block: int = 8,
                           min_coverage: float = 0.75) -> tuple[float, int]:
    """Mean absolute RGB difference (0..1) of ``block`` x ``block`` averages where both cover.

    Blocks averaging hides per-pixel texture aliasing (a mipmapped build against a level-0
    source) while a wrong texture, factor or material still shows. Only blocks covered by
    both images on at least ``min_coverage`` of their pixels count. Returns (difference,
    number of blocks compared).
    """
    h, w = img_a.shape[:2]
    hb, wb = h // block, w // block
    if hb == 0 or wb == 0:
        return 0.0, 0
    both = (coverage(img_a) & coverage(img_b))[: hb * block, : wb * block]
    cov = both.reshape(hb, block, wb, block).mean(axis=(1, 3))
    keep = cov >= min_coverage
    if not keep.any():
        return 0.0, 0

    def means(img: np.ndarray) -> np.ndarray:
        rgb = img[: hb * block, : wb * block, :3].astype(np.float64) / 255.0 * both[..., None]
        return rgb.reshape(hb, block, wb, block, 3).sum(axis=(1, 3)) / np.maximum(
            cov[..., None] * block * block, 1e-9)

    diff = np.abs(means(img_a) - means(img_b))[keep]
    return float(diff.mean()), int(keep.sum())


def block_color_differences(img_a: np.ndarray, img_b: np.ndarray, block: int = 8,
                            min_coverage: float = 0.75) -> np.ndarray:
    """Per compared block (as :func:`block_color_difference`), the largest absolute RGB
    difference (0..1) of its mean colours: (K,) float64, empty when no block is compared."""
    h, w = img_a.shape[:2]
    hb, wb = h // block, w // block
    if hb == 0 or wb == 0:
        return np.zeros(0)
    both = (coverage(img_a) & coverage(img_b))[: hb * block, : wb * block]
    cov = both.reshape(hb, block, wb, block).mean(axis=(1, 3))
    keep = cov >= min_coverage

    def means(img: np.ndarray) -> np.ndarray:
        rgb = img[: hb * block, : wb * block, :3].astype(np.float64) / 255.0 * both[..., None]
        return rgb.reshape(hb, block, wb, block, 3).sum(axis=(1, 3)) / np.maximum(
            cov[..., None] * block * block, 1e-9)

    return np.abs(means(img_a) - means(img_b)).max(axis=-1)[keep]


def image_difference(a: np.ndarray, b: np.ndarray, tolerance: int = 2) -> tuple[int, float]:
    """(max absolute channel difference, fraction of pixels differing by more than ``tolerance``)."""
    if a.shape != b.shape:
        return 255, 1.0
    d = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return int(d.max(initial=0)), float((d.max(axis=-1) > tolerance).mean())
