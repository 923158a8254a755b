"""renderer/cull.py: triangles that cover no pixel centre are left out of a draw, and the pictures
stay the same bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from assetpipe.renderer.camera import fit_camera
from assetpipe.renderer.cull import CULL_MIN_TRIANGLES, Projector, cull
from assetpipe.renderer.loader import Lod, Material, Mesh, RenderModel, Texture


def _ortho_px(width: int, height: int) -> np.ndarray:
    """A view_proj mapping x, y in pixels (z = 0, w = 1) to Vulkan clip space."""
    m = np.eye(4)
    m[0, 0], m[0, 3] = 2.0 / width, -1.0
    m[1, 1], m[1, 3] = 2.0 / height, -1.0
    return m


def _run(tris_px: list, width: int = 8, height: int = 8, offset: float = 0.0, view_proj=None):  # noqa: ANN001, ANN202
    pts = np.array([p for t in tris_px for p in t], np.float64)
    pos = np.c_[pts, np.zeros(len(pts))] + offset
    m = _ortho_px(width, height) if view_proj is None else view_proj
    if offset:
        shift = np.eye(4)
        shift[:3, 3] = -offset
        m = m @ shift
    indices = np.arange(len(pts), dtype=np.uint32)
    kept, counts = cull(Projector(pos.astype(np.float32)), indices, np.array([[0, len(pts), 0]]), m, width, height)
    return [int(i) // 3 for i in kept[::3]], counts


def test_a_triangle_between_pixel_centres_is_dropped_and_one_over_a_centre_kept() -> None:
    between = [(1.6, 1.6), (2.4, 1.6), (1.6, 2.4)]   # inside pixel (1, 1) but short of its centre (1.5, 1.5)
    over = [(2.2, 2.2), (2.9, 2.2), (2.2, 2.9)]      # holds pixel (2, 2)'s centre (2.5, 2.5)
    outside = [(-3.0, 1.0), (-1.0, 1.0), (-1.0, 3.0)]  # left of the picture
    kept, counts = _run([between, over, outside])
    assert kept == [1] and counts.tolist() == [3]


def test_a_box_touching_a_centre_is_kept() -> None:
    """The box test is conservative: a thin triangle whose box holds a centre stays (the
    rasteriser decides), and so does one within the rounding margin of a centre."""
    sliver = [(0.2, 0.2), (3.8, 3.9), (0.3, 0.2)]           # its box holds centres, its area none
    almost = [(1.5 + 1e-4, 1.5), (2.4, 1.5), (1.5 + 1e-4, 2.4)]  # 1e-4 px right of a centre: within the margin
    kept, _ = _run([sliver, almost])
    assert kept == [0, 1]


def test_far_from_the_origin_the_margin_widens() -> None:
    """Positions 1e6 away from the origin lose float32 precision on the GPU: the same triangle
    0.01 px short of a centre is dropped near the origin and kept there."""
    near_miss = [(1.51, 1.51), (2.4, 1.51), (1.51, 2.4)]
    assert _run([near_miss])[0] == []
    assert _run([near_miss], offset=1e6)[0] == [0]


def test_a_corner_behind_the_eye_keeps_the_triangle() -> None:
    cam = fit_camera(np.zeros(3), 1.0, (0.0, 0.0, -1.0), 16, 16)
    eye = np.asarray(cam.eye)
    tri = np.array([eye + (0.0, 0.0, 5.0), eye + (0.001, 0.0, -5.0), eye + (0.0, 0.001, -5.0)])  # spans the eye
    kept, _ = cull(Projector(tri.astype(np.float32)), np.arange(3, dtype=np.uint32), np.array([[0, 3, 0]]),
                   cam.view_proj, 16, 16)
    assert len(kept) == 3


def test_non_finite_positions_keep_everything() -> None:
    pos = np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]], np.float32)
    kept, counts = cull(Projector(pos), np.arange(3, dtype=np.uint32), np.array([[0, 3, 0]]), np.eye(4), 4, 4)
    assert len(kept) == 3 and counts.tolist() == [3]


def _sphere(segments: int, rings: int, center: tuple[float, float, float], radius: float):  # noqa: ANN202
    u, v = np.meshgrid(np.linspace(0, 1, segments + 1), np.linspace(0, 1, rings + 1))
    th, ph = u * 2 * np.pi, v * np.pi
    pos = np.stack([np.cos(th) * np.sin(ph), np.cos(ph), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3) * radius
    pos += center
    i = np.arange(rings)[:, None] * (segments + 1) + np.arange(segments)[None, :]
    a, b, c, d = i, i + 1, i + segments + 1, i + segments + 2
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return pos.astype(np.float32), np.stack([u, v], -1).reshape(-1, 2).astype(np.float32), tris.astype(np.uint32)


def _dense_model() -> RenderModel:
    """Two fine UV spheres (about 84k triangles each): an opaque textured one and a blended one."""
    parts = [_sphere(256, 164, (0.0, 0.0, 0.0), 1.0), _sphere(256, 164, (1.2, 0.3, 0.4), 0.6)]
    checker = np.kron((np.indices((8, 8)).sum(0) % 2).astype(np.uint8) * 200 + 40, np.ones((8, 8), np.uint8))
    tex = Texture("checker", [np.dstack([checker, 255 - checker, checker, np.full_like(checker, 255)])], 43)
    materials = [Material("opaque", texture=tex), Material("blend", base_color=(0.3, 0.6, 0.9, 0.5),
                                                          alpha_mode="BLEND", double_sided=True)]
    meshes, pos, uvs, idx = [], [], [], []
    vbase = ibase = 0
    for k, (p, uv, t) in enumerate(parts):
        meshes.append(Mesh(f"m{k}", k, vbase, len(p), [Lod(0, ibase, t.size)], p.mean(0).astype(np.float64)))
        pos.append(p), uvs.append(uv), idx.append(t.reshape(-1))
        vbase, ibase = vbase + len(p), ibase + t.size
    allp = np.concatenate(pos)
    lo, hi = allp.min(0).astype(np.float64), allp.max(0).astype(np.float64)
    return RenderModel("dense", allp, np.concatenate(uvs), np.ones((len(allp), 4), np.float32),
                       np.concatenate(idx), meshes, materials, lo, hi, (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2))


@pytest.mark.vulkan
def test_culled_renders_equal_full_renders_bit_for_bit() -> None:
    from assetpipe.renderer.session import shared_renderer  # noqa: PLC0415

    model = _dense_model()
    assert model.triangles(0) >= 2 * CULL_MIN_TRIANGLES
    r = shared_renderer(128, 128)
    gpu = r.upload(model)
    try:
        cams = [fit_camera(model.center, model.radius, (-0.6, -0.45, -1.0), 128, 128),
                fit_camera(model.center, model.radius, (0.3, -0.2, 1.0), 48, 48),
                # inside the big sphere, looking out: corners behind the eye
                fit_camera(model.center, model.radius, (0.0, 0.0, -1.0), 128, 128, distance=0.2)]
        for k, cam in enumerate(cams):
            drawn = {}
            for on in (False, True):
                r.cull = on
                drawn[on] = [r.render(gpu, cam, mode=mode) for mode in ("shaded", "facing", "silhouette",
                                                                         "shaded+facing")]
                if on and k < 2:  # (inside, vertices near the eye plane widen the margin: all may stay)
                    draws, _ = r._culled(gpu, r.draws(gpu), cam)
                    assert sum(d.index_count for d in draws) < model.indices.size // 2  # most were left out
            for full, culled in zip(drawn[False], drawn[True]):
                assert full[..., 3].any()
                np.testing.assert_array_equal(full, culled)
    finally:
        r.cull = True
        r.release(gpu)
