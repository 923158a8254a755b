"""The validator on generated assets of every material kind: no false alarm on the good builds,
and every mutation of :mod:`validate_mutations` caught with a message that says what is wrong."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from assetpipe.renderer.batch import validate_batch, validate_model
from assetpipe.renderer.validate import ValidateOptions
from validate_assets import KINDS, write_assets
from validate_mutations import MUTATIONS, NotApplicable, caught

pytestmark = pytest.mark.vulkan
OPTS = ValidateOptions(width=128, height=128)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("validate-assets")
    write_assets(root / "src")
    res = CliRunner().invoke(main, ["build", str(root / "src"), "-o", str(root / "out"), "--cache",
                                    str(root / "cache"), "-q"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return root


def test_every_material_kind_passes(built: Path) -> None:
    """Zero false alarms: metal-rough with every texture role, spec-gloss, MASK, BLEND, texture
    transform, vertex colours, a second UV set, a renormalised normal map."""
    results = validate_batch([built / "out" / f"{k}.json" for k in KINDS], OPTS, isolate=False)
    assert [r.failures() for r in results if not r.passed] == []
    by_id = {r.id: r for r in results}
    # the three false alarms, each reproduced by a fixture:
    tex = by_id["pbr"].check("textures")
    emissive = tex.figures["pbr-mat-0/emissive"]
    assert max(emissive["level0MeanCodes"]) < 1.5 and emissive["levels"] == 9  # mostly black: small mips black
    normal = by_id["normalmap"].check("textures").figures["normalmap-mat-0/normal"]
    assert normal["level0VsImage"] <= 1 / 255  # level 0 = the PNG renormalised, not its bytes
    sg = by_id["specgloss"].check("source")
    assert sg.status == "pass" and sg.measured["colorDiff"] < 0.01, sg.figures
    roles = by_id["pbr"].check("roles")
    assert set(roles.figures) == {f"pbr-mat-0/{r}" for r in ("baseColor", "metallicRoughness", "normal",
                                                             "occlusion", "emissive")}


def test_the_old_rules_would_have_flagged_the_fixtures(built: Path) -> None:
    """The fixtures do reproduce the false alarms: the emissive's top levels are all black, the
    normal map's PNG bytes differ from the KTX2's level 0."""
    import numpy as np

    from assetpipe.core.ktx2 import read_ktx2
    from assetpipe.renderer.checks.images import decode_rgba

    import json
    side = json.loads((built / "out" / "pbr.asset.json").read_text())
    em = side["materials"][0]["textures"]["emissive"]
    levels = read_ktx2((built / "out" / em["ktx2"]).read_bytes()).levels
    assert levels[0][..., :3].any() and not np.asarray(levels[-1])[..., :3].any()
    side = json.loads((built / "out" / "normalmap.asset.json").read_text())
    nm = side["materials"][0]["textures"]["normal"]
    png = decode_rgba((built / "out" / nm["path"]).read_bytes())
    lv0 = np.asarray(read_ktx2((built / "out" / nm["ktx2"]).read_bytes()).levels[0])
    assert np.abs(png.astype(int) - lv0).mean() / 255 > 2 / 255
    # the soft mask: its coverage-keeping chain moves the small levels' premultiplied means (the
    # old rule, over its tolerance), not their alpha-weighted colour (the rule now, for MASK)
    from assetpipe.renderer.checks.textures import _linear_premultiplied, _mean_colour, sample

    side = json.loads((built / "out" / "masksoft.asset.json").read_text())
    ms = side["materials"][0]["textures"]["baseColor"]
    texels = [sample(np.asarray(lv)) for lv in read_ktx2((built / "out" / ms["ktx2"]).read_bytes()).levels]
    old = [float(np.abs(_linear_premultiplied(t, True).mean(0) - _linear_premultiplied(texels[0], True).mean(0)).max())
           for t in texels]
    new = [float(np.abs(_mean_colour(t, True, True) - _mean_colour(texels[0], True, True)).max()) for t in texels]
    assert max(old) > OPTS.texture_mean_tolerance > 10 * max(new), (old, new)


@pytest.mark.parametrize("kind", list(MUTATIONS))
def test_mutation_is_caught(built: Path, kind: str, tmp_path: Path) -> None:
    mutate, checks, phrase = MUTATIONS[kind]
    shutil.copytree(built / "out", tmp_path / "out")
    model = tmp_path / "out" / "pbr.json"
    try:
        mutate(model)
    except NotApplicable as exc:  # every mutation applies to the pbr fixture
        pytest.fail(f"{kind}: {exc}")
    r = validate_model(model, OPTS, isolate=False)
    ok, lines = caught(r, checks, phrase)
    assert ok, f"{kind} not caught by {checks} with {phrase!r}: {lines or 'passed'}"


@pytest.mark.parametrize("model", ["pbr", "mask", "multiuv", "orm"])
def test_the_smallest_validate_size_still_sees_a_shrunk_model(built: Path, model: str, tmp_path: Path) -> None:
    """MIN_VALIDATE_SIZE: at it, the fixtures shrunk by a tenth fail the source check (at 4 px they
    passed every check); unshrunk, they pass there: no false alarm from the small picture."""
    from assetpipe.renderer.results import MIN_VALIDATE_SIZE

    small = ValidateOptions(width=MIN_VALIDATE_SIZE, height=MIN_VALIDATE_SIZE)
    mutate, checks, phrase = MUTATIONS["shrunk by a tenth"]
    shutil.copytree(built / "out", tmp_path / "out")
    target = tmp_path / "out" / f"{model}.json"
    assert validate_model(target, small, isolate=False).passed
    mutate(target)
    ok, lines = caught(validate_model(target, small, isolate=False), checks, phrase)
    assert ok, lines or "passed"


def test_a_hole_a_double_sided_closed_mesh_hides_is_caught(built: Path, tmp_path: Path) -> None:
    """Through a hole in a double-sided sphere the inside shows, so every picture is covered: the
    open edges give it away."""
    mutate, _, _ = MUTATIONS["LOD level with a hole"]
    shutil.copytree(built / "out", tmp_path / "out")
    model = tmp_path / "out" / "mask.json"
    mutate(model)
    r = validate_model(model, OPTS, isolate=False)
    lods = r.check("lods")
    assert lods.status == "fail" and "a hole?" in " ".join(lods.messages), lods.messages
    assert lods.measured["openEdgeGrowth"] > lods.tolerance["openEdgeGrowth"]


def _turn_channel(model: Path, role: str, channel: int) -> None:
    """Turn one channel of ``role``'s texture 180 degrees (the KTX2 chain and the level-0 image alike)."""
    import json

    import cv2
    import numpy as np

    from assetpipe.core.ktx2 import read_ktx2, write_ktx2

    side = json.loads(model.with_name(model.name[:-5] + ".asset.json").read_text())
    tex = side["materials"][0]["textures"][role]
    path = model.parent / tex["ktx2"]
    img = read_ktx2(path.read_bytes())
    levels = [np.array(lv) for lv in img.levels]
    for lv in levels:
        lv[..., channel] = lv[::-1, ::-1, channel]
    path.write_bytes(write_ktx2(levels, int(img.vk_format)))
    png = model.parent / tex["path"]
    data = cv2.imdecode(np.fromfile(png, np.uint8), cv2.IMREAD_UNCHANGED)
    bgr = {0: 2, 1: 1, 2: 0}[channel]  # OpenCV's channel order
    data[..., bgr] = data[::-1, ::-1, bgr]
    png.write_bytes(cv2.imencode(".png", data)[1].tobytes())


@pytest.mark.parametrize("kind,model", [("wrong normal map (consistent)", "orm"),
                                        ("wrong metallic-roughness (consistent)", "orm"),
                                        ("wrong emissive (consistent)", "pbr"),
                                        ("wrong texture (consistent)", "orm"),
                                        ("occlusion channel only", "orm"),
                                        ("metallic channel only", "orm")])
def test_a_wrong_texture_in_each_role_changes_the_shaded_picture(built: Path, kind: str, model: str,
                                                                  tmp_path: Path) -> None:
    """Every texture role is drawn in the shaded picture (build and source alike): a wrong texture in
    any role moves its block means past the colour tolerance, so ``source`` fails as well as ``roles``.
    The ``orm`` kind packs occlusion (R), roughness (G) and metallic (B) in one texture on the base
    colour's UV set; turning a single channel shows each of the three is drawn."""
    shutil.copytree(built / "out", tmp_path / "out")
    target = tmp_path / "out" / f"{model}.json"
    channel = {"occlusion channel only": 0, "roughness channel only": 1, "metallic channel only": 2}.get(kind)
    if channel is None:
        MUTATIONS[kind][0](target)
    else:
        _turn_channel(target, "metallicRoughness", channel)
    r = validate_model(target, OPTS, isolate=False)
    src = r.check("source")
    assert src.status == "fail" and any("shaded colours differ" in m for m in src.messages), (src.figures,
                                                                                             src.messages)
    assert src.measured["colorDiff"] > src.tolerance["colorDiff"]
    assert r.check("roles").status == "fail", r.check("roles").figures


def test_every_role_is_drawn_for_build_and_source(built: Path) -> None:
    """The orm kind's build and source reference both carry all five roles to the renderer."""
    from assetpipe.renderer.loader import load_built_model
    from assetpipe.renderer.source_model import load_source_model

    roles = ("texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture", "emissive_texture")
    b = load_built_model(built / "out" / "orm.json").materials[0]
    s = load_source_model(built / "src" / "orm.glb").materials[0]
    assert [getattr(b, a) is not None for a in roles] == [True, True, True, True, False]
    assert [getattr(s, a) is not None for a in roles] == [True, True, True, True, False]
    # the reference samples a mip chain of its own, down to 1x1, with the glTF sampler
    assert [lv.shape[:2] for lv in s.texture.levels][-2:] == [(2, 2), (1, 1)]
    assert s.texture.sampler.get("minFilter") == 9987


def test_roughness_alone_moves_the_highlights_only(built: Path, tmp_path: Path) -> None:
    """Roughness (G) alone changes the specular highlights only, small on the mostly dielectric orm
    sphere: the picture moves (a roughness that was not drawn would leave it identical, colorDiff 0),
    but by less than the colour tolerance; ``roles`` catches it."""
    shutil.copytree(built / "out", tmp_path / "out")
    target = tmp_path / "out" / "orm.json"
    _turn_channel(target, "metallicRoughness", 1)
    r = validate_model(target, OPTS, isolate=False)
    moved = max(v["colorDiff"] for v in r.check("source").figures["views"])
    assert 0.001 < moved, r.check("source").figures
    assert r.check("roles").status == "fail", r.check("roles").figures


@pytest.mark.parametrize("model", ["multiuv", "transform"])
def test_flipped_v_on_another_uv_set_or_through_a_transform_is_caught(built: Path, model: str,
                                                                      tmp_path: Path) -> None:
    """The reference reads the UV set the base colour samples (TEXCOORD_1 here) with its
    KHR_texture_transform applied, which trimesh alone does not: the uvs check compares them."""
    shutil.copytree(built / "out", tmp_path / "out")
    good = validate_model(tmp_path / "out" / f"{model}.json", OPTS, isolate=False).check("uvs")
    assert good.status == "pass" and good.figures["maxUvError"] == 0.0, (good.messages, good.figures)
    MUTATIONS["flipped V"][0](tmp_path / "out" / f"{model}.json")
    uvs = validate_model(tmp_path / "out" / f"{model}.json", OPTS, isolate=False).check("uvs")
    assert uvs.status == "fail" and "flipped or shifted UVs" in uvs.messages[0], uvs.messages


@pytest.fixture(scope="module")
def built_uv1(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The pbr kind (occlusion on TEXCOORD_1) built with a layout that carries the second UV set."""
    root = tmp_path_factory.mktemp("validate-uv1")
    write_assets(root / "src", ("pbr",))
    res = CliRunner().invoke(main, ["build", str(root / "src"), "-o", str(root / "out"), "--cache",
                                    str(root / "cache"), "--layout", "position,uv0,uv1", "-q"],
                             catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return root


def test_a_role_on_the_second_uv_set_is_drawn_from_uv1(built_uv1: Path, tmp_path: Path) -> None:
    """With ``uv1`` in the layout the occlusion on TEXCOORD_1 is drawn from it, by the build and by
    the reference (which reads TEXCOORD_1 itself): the good build passes, and a wrong occlusion
    texture fails ``source`` (the shaded picture) as well as ``roles``."""
    from assetpipe.renderer.loader import load_built_model
    from assetpipe.renderer.source_model import load_source_model

    model = built_uv1 / "out" / "pbr.json"
    built = load_built_model(model)
    assert built.uvs1 is not None and built.materials[0].occlusion_texture is not None
    assert built.materials[0].role_uv == (0, 0, 1, 0)  # normal, metallic-roughness, occlusion, emissive
    src = load_source_model(built_uv1 / "src" / "pbr.glb")
    assert src.materials[0].occlusion_texture is not None and src.materials[0].role_uv == (0, 0, 1, 0)
    np.testing.assert_allclose(src.uvs1.min(0), [0.25, 0.25], atol=1e-6)  # the fixture's uv1 = uv0 / 2 + 1/4
    good = validate_model(model, OPTS, isolate=False)
    assert good.passed, good.failures()
    assert good.check("source").measured["colorDiff"] <= good.check("source").tolerance["colorDiff"]
    shutil.copytree(built_uv1 / "out", tmp_path / "out")
    MUTATIONS["wrong occlusion (consistent)"][0](tmp_path / "out" / "pbr.json")
    r = validate_model(tmp_path / "out" / "pbr.json", OPTS, isolate=False)
    s = r.check("source")
    assert s.status == "fail" and any("shaded colours differ" in m for m in s.messages), (s.figures, s.messages)
    assert r.check("roles").status == "fail"


def test_a_role_on_a_uv_set_the_layout_lacks_is_named(built: Path) -> None:
    """The default layout (position, uv0) does not carry TEXCOORD_1: the validator says which role
    it cannot draw and why, and draws it on neither side (no false alarm)."""
    r = validate_model(built / "out" / "pbr.json", OPTS, isolate=False)
    assert r.passed, r.failures()
    assert any("the occlusion texture is not drawn: it samples TEXCOORD_1, which the build's vertex layout "
               "does not carry" in n for n in r.notes), r.notes
    assert any("['occlusion'] on TEXCOORD_1 drawn on neither side" in c
               for c in r.check("source").figures.get("caveats", [])), r.check("source").figures


def test_source_textures_made_side_by_side_are_the_same(built: Path, monkeypatch) -> None:
    """The reference's images are decoded and mipped on TEXTURE_THREADS threads before the
    materials are assembled: the same materials, levels and notes as one at a time."""
    from assetpipe.renderer import source_model

    src = built / "src" / "pbr.glb"
    models = []
    for threads in (1, 4):
        monkeypatch.setattr(source_model, "TEXTURE_THREADS", threads)
        models.append(source_model.load_source_model(src, decoded={}))
    a, b = models
    assert a.notes == b.notes and len(a.materials) == len(b.materials) == 1
    roles = ("texture", "normal_texture", "metallic_roughness_texture", "occlusion_texture", "emissive_texture")
    drawn = 0
    for ma, mb in zip(a.materials, b.materials):
        for role in roles:
            ta, tb = getattr(ma, role), getattr(mb, role)
            assert (ta is None) == (tb is None)
            if ta is not None:
                drawn += 1
                assert ta.name == tb.name and ta.vk_format == tb.vk_format and ta.sampler == tb.sampler
                assert [lv.tobytes() for lv in ta.levels] == [lv.tobytes() for lv in tb.levels]
    assert drawn >= 4  # base colour, normal, metallic-roughness, emissive (occlusion is on TEXCOORD_1)
