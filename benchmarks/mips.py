"""Mip chain benchmark: our gamma-correct chain against Pillow's naive repeated reduce(2).

    .venv/bin/python benchmarks/mips.py [--size 4096] [--repeats 7]

One 4096 x 4096 RGBA8 image (fixed seed: smooth gradients + multi-scale noise, a
photographic-like spectrum, opaque), the full 13-level chain. Both contenders run in the same
process, interleaved, several times; the table shows the median time of each, our time as a
ratio to Pillow's, the level-0 Mtexels per second, and the accuracy of both against a float64
reference (the exact area average of level 0 in linear light, re-encoded to sRGB without
rounding) for level 1 and the smallest levels.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
from PIL import Image  # noqa: E402

from assetpipe.pipelines.texture_mips import build_mip_chain, linear_to_srgb, mip_sizes, srgb_to_linear  # noqa: E402


def make_image(size: int, seed: int = 1234) -> np.ndarray:
    """(size, size, 4) uint8: gradients + noise at several scales, alpha 255."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:size, :size].astype(np.float32) / size
    img = np.empty((size, size, 3), np.float32)
    img[..., 0] = 0.15 + 0.6 * x
    img[..., 1] = 0.2 + 0.5 * y
    img[..., 2] = 0.5 + 0.3 * np.sin(6.0 * x + 4.0 * y)
    for cells, amp in ((8, 0.25), (64, 0.12), (512, 0.08)):
        noise = rng.standard_normal((cells, cells, 3)).astype(np.float32)
        img += amp * cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    img += 0.06 * rng.standard_normal((size, size, 3)).astype(np.float32)  # texel-level grain
    rgba = np.full((size, size, 4), 255, np.uint8)
    rgba[..., :3] = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return rgba


def pillow_chain(rgba: np.ndarray) -> list[np.ndarray]:
    im = Image.fromarray(rgba, "RGBA")
    levels = [im]
    while max(im.size) > 1:
        im = im.reduce(2)
        levels.append(im)
    return levels


def reference_levels(rgba: np.ndarray, wanted: list[int]) -> dict[int, np.ndarray]:
    """Float64 sRGB (0..255, unrounded) of the exact linear-light area average of level 0,
    for the level indices in ``wanted``. Uses exact block sums (power-of-two sides)."""
    lin = srgb_to_linear(rgba[..., :3] / 255.0)
    h0, w0 = rgba.shape[:2]
    sizes = mip_sizes(w0, h0)
    out = {}
    for k in wanted:
        w, h = sizes[k]
        assert h0 % h == 0 and w0 % w == 0
        block = lin.reshape(h, h0 // h, w, w0 // w, 3).mean(axis=(1, 3))
        out[k] = linear_to_srgb(block) * 255.0
    return out


def median_times(fns: dict, repeats: int) -> dict[str, float]:
    times: dict[str, list[float]] = {name: [] for name in fns}
    for name, fn in fns.items():  # warm-up (tables, caches, thread pools)
        fn()
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    return {name: statistics.median(ts) for name, ts in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    rgba = make_image(args.size)
    n_levels = len(mip_sizes(args.size, args.size))
    print(f"image {args.size}x{args.size} RGBA8, {n_levels} levels; cv2 {cv2.__version__}, "
          f"threads {cv2.getNumThreads()}; median of {args.repeats} interleaved runs")

    t = median_times({
        "assetpipe gamma-correct": lambda: build_mip_chain(rgba, "baseColor"),
        "Pillow reduce(2), naive": lambda: pillow_chain(rgba),
    }, args.repeats)

    ours = build_mip_chain(rgba, "baseColor").levels
    pil = [np.asarray(im) for im in pillow_chain(rgba)]
    check = [1, 2, n_levels - 3, n_levels - 2, n_levels - 1]
    refs = reference_levels(rgba, check)

    def errs(levels) -> list[str]:
        cells = []
        for k in check:
            d = np.abs(levels[k][..., :3].astype(np.float64) - refs[k])
            cells.append(f"{d.max():5.2f}/{d.mean():5.2f}")
        return cells

    mtex = args.size * args.size / 1e6
    base = t["Pillow reduce(2), naive"]
    header = ["chain", "median ms", "ratio", "Mtexel/s"] + [
        f"L{k} {mip_sizes(args.size, args.size)[k][0]}px max/mean" for k in check]
    rows = []
    for name, levels in (("assetpipe gamma-correct", ours), ("Pillow reduce(2), naive", pil)):
        rows.append([name, f"{t[name] * 1e3:.1f}", f"{t[name] / base:.2f}x", f"{mtex / t[name]:.0f}"] + errs(levels))
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    line = "  ".join("{:<%d}" % w for w in widths)
    print(line.format(*header))
    for r in rows:
        print(line.format(*r))
    print("errors: |level - float64 reference| in 8-bit sRGB units (reference: exact area average in "
          "linear light, unrounded)")


if __name__ == "__main__":
    main()
