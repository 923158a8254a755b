"""Golden images: renders of a few simple models compared with PNGs in ``tests/data/golden/``.

``python -m renderer.goldens --update`` re-renders and rewrites them; without ``--update`` it
compares and exits 1 on a mismatch. Models:

* ``cube``: the hand-made fixture ``tests/data/built/cube`` (always available);
* ``BoxTextured``, ``AlphaBlendModeTest``, ``TextureSettingsTest``, ``VertexColorTest``:
  built from the shared corpus with ``assetpipe build`` into a temporary directory (skipped
  with a message when the corpus or the build is unavailable).

A render matches its golden when no channel differs by more than ``MAX_DIFF`` on more than
``MAX_FRACTION`` of the pixels (lavapipe is deterministic on one Mesa version; the
tolerance absorbs rounding differences between Mesa/LLVM versions).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from .camera import fit_camera
from .compare import image_difference

REPO = Path(__file__).resolve().parents[1]
GOLDEN_DIR = REPO / "tests" / "data" / "golden"
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
SIZE = 256
VIEWS = {"front": (-0.6, -0.45, -1.0), "top": (0.2, -1.0, 0.3)}
MAX_DIFF = 3
MAX_FRACTION = 0.005
CORPUS_MODELS = ("BoxTextured", "AlphaBlendModeTest", "TextureSettingsTest", "VertexColorTest")


@dataclass
class GoldenOutcome:
    """One comparison: name, whether it matched, the figures, and a message."""

    name: str
    ok: bool
    max_diff: int = 0
    fraction: float = 0.0
    message: str = ""


def render_views(model_json: Path) -> dict[str, np.ndarray]:
    """The golden renders of ``model_json``: view name -> (SIZE, SIZE, 4) uint8."""
    from .loader import load_built_model  # noqa: PLC0415
    from .session import shared_renderer  # noqa: PLC0415

    model = load_built_model(model_json)
    r = shared_renderer(SIZE, SIZE)
    gpu = r.upload(model)
    try:
        return {v: r.render(gpu, fit_camera(model.center, model.radius, d, SIZE, SIZE)) for v, d in VIEWS.items()}
    finally:
        r.release(gpu)


def build_corpus_model(name: str, out: Path) -> Path | None:
    """``assetpipe build`` one corpus model into ``out``; the ``ID.json`` built, or None."""
    src = CORPUS / name
    if not src.is_dir():
        return None
    exe = Path(sys.executable).with_name("assetpipe")
    cmd = [str(exe)] if exe.is_file() else [sys.executable, "-m", "assetpipe.cli"]
    proc = subprocess.run(cmd + ["build", str(src), "-o", str(out), "--cache", str(out / ".cache"), "-q"], capture_output=True, text=True, timeout=600)
    found = sorted(p for p in out.glob("*.json") if not p.name.endswith((".asset.json", "-mat.json")))
    return found[0] if proc.returncode == 0 and found else None


def golden_models(workdir: Path, only: list[str] | None = None) -> dict[str, Path | None]:
    """name -> built ID.json (None when it could not be built); ``only`` restricts the names."""
    models: dict[str, Path | None] = {}
    if not only or "cube" in only:
        models["cube"] = REPO / "tests" / "data" / "built" / "cube" / "cube.json"
    for name in CORPUS_MODELS:
        if not only or name in only:
            models[name] = build_corpus_model(name, workdir / name)
    return models


def compare_model(name: str, model_json: Path, update: bool = False) -> list[GoldenOutcome]:
    """Compare (or with ``update`` rewrite) the goldens of one model."""
    out = []
    for view, img in render_views(model_json).items():
        path = GOLDEN_DIR / f"{name}-{view}.png"
        if update:
            GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
            Image.fromarray(img, "RGBA").save(path, optimize=True)
            out.append(GoldenOutcome(f"{name}-{view}", True, message="updated"))
            continue
        if not path.is_file():
            out.append(GoldenOutcome(f"{name}-{view}", False, message=f"no golden {path}"))
            continue
        ref = np.asarray(Image.open(path).convert("RGBA"))
        mx, frac = image_difference(img, ref, MAX_DIFF)
        ok = frac <= MAX_FRACTION
        out.append(GoldenOutcome(f"{name}-{view}", ok, mx, frac,
                                 "" if ok else f"{frac:.2%} of pixels differ by more than {MAX_DIFF}"))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m renderer.goldens", description=__doc__.splitlines()[0])
    ap.add_argument("--update", action="store_true", help="rewrite the golden PNGs")
    ap.add_argument("--only", nargs="*", help="model names (default: all)")
    args = ap.parse_args(argv)
    failed = 0
    with tempfile.TemporaryDirectory(prefix="assetpipe-goldens-") as tmp:
        for name, model_json in golden_models(Path(tmp), args.only).items():
            if model_json is None:
                print(f"skip   {name}: could not build it from {CORPUS / name}")
                continue
            for o in compare_model(name, model_json, args.update):
                print(f"{'ok    ' if o.ok else 'FAIL  '}{o.name}: max diff {o.max_diff}, "
                      f"{o.fraction:.3%} > {MAX_DIFF} {o.message}")
                failed += not o.ok
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
