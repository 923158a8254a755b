"""The headless Vulkan context and the offscreen renderer on lavapipe."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from assetpipe.renderer.camera import fit_camera, project_points
from assetpipe.renderer.loader import load_built_model
from assetpipe.renderer.session import shared_renderer

pytestmark = pytest.mark.vulkan
CUBE = Path(__file__).parent / "data" / "built" / "cube" / "cube.json"


def test_device_is_lavapipe_vulkan_13() -> None:
    r = shared_renderer()
    assert "llvmpipe" in r.ctx.info.name
    major, minor = (int(x) for x in r.ctx.info.api_version.split(".")[:2])
    assert (major, minor) >= (1, 3)
    assert r.ctx.validation


def test_render_cube_is_not_empty_and_clean() -> None:
    r = shared_renderer()
    r.ctx.take_messages()
    model = load_built_model(CUBE)
    gpu = r.upload(model)
    try:
        cam = fit_camera(model.center, model.radius, width=128, height=128)
        img = r.render(gpu, cam)
        sil = r.render(gpu, cam, mode="silhouette")
    finally:
        r.release(gpu)
    assert img.shape == (128, 128, 4) and img.dtype == np.uint8
    covered = sil[..., 3] > 0
    assert 0.1 < covered.mean() < 0.9
    # the silhouette's box matches the CPU projection of the vertices
    px, front = project_points(cam, model.positions)
    assert front.all()
    ys, xs = np.nonzero(covered)
    assert abs(xs.min() - px[:, 0].min()) <= 1.5 and abs(xs.max() + 1 - px[:, 0].max()) <= 1.5
    assert abs(ys.min() - px[:, 1].min()) <= 1.5 and abs(ys.max() + 1 - px[:, 1].max()) <= 1.5
    assert r.ctx.take_messages() == []


def test_renders_are_deterministic() -> None:
    r = shared_renderer()
    model = load_built_model(CUBE)
    gpu = r.upload(model)
    try:
        cam = fit_camera(model.center, model.radius, width=96, height=96)
        a, b = r.render(gpu, cam), r.render(gpu, cam)
    finally:
        r.release(gpu)
    assert np.array_equal(a, b)


def test_back_faces_are_culled_unless_double_sided() -> None:
    """Looking at the cube from inside: single-sided faces vanish (culled), the quad stays."""
    r = shared_renderer()
    model = load_built_model(CUBE)
    gpu = r.upload(model)
    try:
        cam = fit_camera(np.zeros(3), 1.0, view_dir=(0, 0, -1), width=64, height=64, distance=0.05)
        img = r.render(gpu, cam, meshes=[0])
        sil = r.render(gpu, cam, mode="coverage", meshes=[0])
    finally:
        r.release(gpu)
    assert (img[..., 3] > 0).sum() == 0       # inside a closed cube all faces are back faces
    assert (sil[..., 3] > 0).all()             # coverage mode draws every triangle


def _run(code: str, **env: str) -> str:
    import os
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**os.environ, **env}, cwd=Path(__file__).resolve().parents[1])
    return proc.stdout + proc.stderr


def test_missing_lavapipe_icd_names_the_packages() -> None:
    out = _run("from renderer._vk import load_vulkan\n"
               "from assetpipe.core.errors import RenderError\n"
               "try:\n    load_vulkan()\nexcept RenderError as e:\n    print('RenderError', e)\n",
               ASSETPIPE_VK_ICD="/nonexistent/lvp_icd.json")
    assert "RenderError" in out and "mesa-vulkan-drivers libvulkan1" in out


def test_missing_libvulkan_names_the_packages() -> None:
    """``import vulkan`` raising OSError (libvulkan.so.1 absent) becomes a RenderError."""
    out = _run("import builtins\n"
               "real = builtins.__import__\n"
               "def fake(name, *a, **k):\n"
               "    if name == 'vulkan':\n        raise OSError('libvulkan.so.1: cannot open shared object file')\n"
               "    return real(name, *a, **k)\n"
               "builtins.__import__ = fake\n"
               "from renderer.vk_context import VkContext\n"
               "from assetpipe.core.errors import RenderError\n"
               "try:\n    VkContext()\nexcept RenderError as e:\n    print('RenderError', e)\n")
    assert "RenderError" in out and "libvulkan.so.1" in out and "vulkan-validationlayers glslang-tools" in out
