"""Renderer.render_pair: the shaded and the facing picture of one view from one pass (OPAQUE models)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from assetpipe.renderer.camera import fit_camera
from assetpipe.renderer.loader import load_built_model
from assetpipe.renderer.results import DEFAULT_VIEWS
from assetpipe.renderer.session import shared_renderer

pytestmark = pytest.mark.vulkan
CUBE = Path(__file__).parent / "data" / "built" / "cube" / "cube.json"


def _pairs(model):  # noqa: ANN001, ANN202
    r = shared_renderer(128, 128)
    gpu = r.upload(model)
    try:
        out = []
        for v in DEFAULT_VIEWS:
            cam = fit_camera(model.center, model.radius, v, 128, 128)
            out.append(((r.render(gpu, cam), r.render(gpu, cam, mode="facing")), r.render_pair(gpu, cam),
                        r.one_pass(gpu)))
        return out
    finally:
        r.release(gpu)


def _opaque(model, double_sided: bool | None = None):  # noqa: ANN001, ANN202
    """The model with every material OPAQUE (the fixture's second material is BLEND)."""
    return dataclasses.replace(model, materials=[
        dataclasses.replace(m, alpha_mode="OPAQUE", double_sided=m.double_sided if double_sided is None
                            else double_sided) for m in model.materials])


def test_one_pass_equals_two_renders_on_a_closed_opaque_model() -> None:
    model = _opaque(load_built_model(CUBE))
    for (s1, f1), (shaded, facing), one in _pairs(model):  # (two renders), (one pass)
        assert one
        assert facing[..., 3].any()
        # the checks read coverage (alpha > 0) and front (red > 220) from the facing picture
        np.testing.assert_array_equal(facing[..., 3] > 0, f1[..., 3] > 0)
        np.testing.assert_array_equal(facing[..., 0] > 220, f1[..., 0] > 220)
        # a closed mesh's nearest surface always faces the eye: culling changes nothing
        np.testing.assert_array_equal(shaded, s1)


def test_back_faces_show_in_the_one_pass_facing() -> None:
    """The cube drawn inside out (every triangle reversed, single-sided): the facing picture marks
    the same pixels as back faces in both ways of rendering."""
    model = _opaque(load_built_model(CUBE), double_sided=False)
    inside_out = dataclasses.replace(model, indices=model.indices.reshape(-1, 3)[:, ::-1].reshape(-1).copy())
    for (s1, f1), (shaded, facing), _ in _pairs(inside_out):  # (two renders), (one pass)
        covered = facing[..., 3] > 0
        assert covered.any() and (facing[..., 0] > 220)[covered].mean() < 0.5  # mostly back faces nearest
        np.testing.assert_array_equal(f1[..., 0] > 220, facing[..., 0] > 220)
        np.testing.assert_array_equal(f1[..., 3] > 0, covered)
        np.testing.assert_array_equal(shaded[..., 3] > 0, covered)
        # culled, the far (now front-facing) walls show; the one pass shows the near walls' backs:
        # other colours where both cover (the difference render_pair documents)
        both = covered & (s1[..., 3] > 0)
        assert both.sum() > covered.sum() // 2 and (shaded[both, :3] != s1[both, :3]).any()


def test_blended_materials_fall_back_to_two_renders() -> None:
    blended = load_built_model(CUBE)  # its second material is BLEND
    for (s1, f1), (shaded, facing), one in _pairs(blended):  # (two renders), (render_pair)
        assert not one
        np.testing.assert_array_equal(shaded, s1)
        np.testing.assert_array_equal(facing, f1)


def test_the_normal_map_is_in_the_shaded_picture(tmp_path: Path) -> None:
    """A normal-mapped generated model: drawn with its normal map the picture differs from the
    same model drawn without it (the renderer reads the map in a per-pixel tangent frame)."""
    import subprocess
    import sys

    from assetpipe.renderer import compare
    from validate_assets import write_assets

    write_assets(tmp_path / "src", kinds=("normalmap",))
    subprocess.run([str(Path(sys.executable).with_name("assetpipe")), "build", str(tmp_path / "src"), "-o",
                    str(tmp_path / "out"), "--cache", str(tmp_path / "cache"), "-q"], check=True)
    model = load_built_model(tmp_path / "out" / "normalmap.json")
    assert any(m.normal_texture is not None for m in model.materials)
    flat = dataclasses.replace(model, materials=[dataclasses.replace(m, normal_texture=None)
                                                 for m in model.materials])
    r = shared_renderer(128, 128)
    pictures = []
    for mdl in (model, flat):
        gpu = r.upload(mdl)
        try:
            pictures.append(r.render(gpu, fit_camera(mdl.center, mdl.radius, DEFAULT_VIEWS[0], 128, 128)))
        finally:
            r.release(gpu)
    diff, blocks = compare.block_color_difference(*pictures)
    assert blocks > 0 and diff > 0.005, diff  # measured 0.019 at 256 px
