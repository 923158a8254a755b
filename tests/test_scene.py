"""Scene files: parsing the seed form, one-line errors, transforms, level selection, planning,
attribute needs, shared materials, and the scene output."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from assetpipe.core.errors import SceneError
from assetpipe.scene import (
    ModelKey,
    attribute_reasons,
    attributes_needed,
    check_shared_materials,
    compose_ops,
    distance_for_screen_px,
    encode_scene_output,
    level_at,
    load_scene,
    max_stretch,
    next_pow2,
    plan_scene,
    scene_name,
    select_levels,
    sphere_screen_px,
)
from assetpipe.pipelines.lod_options import LodOptions
from assetpipe.pipelines.texture_options import TextureOptions

SCENES = Path(__file__).resolve().parent / "data" / "scenes"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _write(folder: Path, data, name: str = "bad.scene.json") -> Path:
    p = folder / name
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return p


def _scene_with(folder: Path, *objects, **scene_keys) -> Path:
    """A scene file in ``folder`` (next to copies of the fixture models) with these objects."""
    for f in ("plane.obj", "sphere.obj"):
        (folder / f).write_bytes((SCENES / f).read_bytes())
    (folder / "monkey").mkdir(exist_ok=True)
    for f in (SCENES / "monkey").iterdir():
        (folder / "monkey" / f.name).write_bytes(f.read_bytes())
    return _write(folder, {"scene": {**scene_keys, "objects": list(objects)}})


# -- the seed form ---------------------------------------------------------------------------

def test_seed_example_parses():
    sc = load_scene(SCENES / "seed.scene.json")
    assert sc.name == "seed"
    assert sc.ambient_light == (1.0, 1.0, 1.0, 0.2)
    assert sc.texture_budget is None
    assert len(sc.objects) == 3
    plane, sphere, monkey = sc.objects
    assert [o.index for o in sc.objects] == [0, 1, 2]
    # paths are resolved relative to the scene file
    assert plane.model == (SCENES / "plane.obj").resolve()
    assert plane.lod_files == () and plane.final_clamp is None and plane.texture is None
    # no instances key: one untransformed instance
    assert len(plane.instances) == 1 and np.array_equal(plane.instances[0], np.eye(4))
    assert sphere.light == {"color": [1.0, 1.0, 1.0, 1.0]}
    assert monkey.model is None
    assert [p.name for p in monkey.lod_files] == ["monkey0.obj", "monkey1.obj", "monkey2.obj"]
    assert monkey.final_clamp == 100.0
    assert monkey.texture == (SCENES / "monkey" / "monkey.png").resolve()
    assert monkey.key.handmade and monkey.key.sources == monkey.lod_files
    for o in sc.objects:
        assert o.view_distance is None and o.max_screen_px is None
        for m in o.instances:
            assert m.shape == (4, 4) and m.dtype == np.float64


def test_seed_instance_ops_compose_in_list_order():
    sc = load_scene(SCENES / "seed.scene.json")
    # [{"translation": t}, {"scaling": s}]: scaled in place, then placed at t
    m = sc.objects[1].instances[0]
    assert np.allclose(m @ [0, 0, 0, 1], [10, -40, 15, 1])
    assert np.allclose(m @ [1, 0, 0, 1], [10.1, -40, 15, 1])
    # [{"rotationX": 180}, {"translation": [1, 1, 1]}]: translated, then rotated about X
    m = sc.objects[2].instances[0]
    assert np.allclose(m @ [0, 0, 0, 1], [1, -1, -1, 1])
    assert np.array_equal(m[:3, :3], np.diag([1.0, -1.0, -1.0]))  # multiples of 90 are exact


def test_extended_example_parses():
    sc = load_scene(SCENES / "town.scene.json")
    assert sc.name == "town" and sc.texture_budget == 1024
    plane, pyramid, crate, monkey = sc.objects
    assert plane.lod_ratios == (1.0,)
    assert pyramid.model == (EXAMPLES / "pyramid" / "pyramid.obj").resolve()
    assert pyramid.lod_ratios == (1.0, 0.5, 0.25) and pyramid.final_clamp == 200
    assert pyramid.view_distance == (5.0, 400.0) and len(pyramid.instances) == 2
    assert crate.lod_ratios is None and crate.max_screen_px == 300
    assert monkey.view_distance == (10.0, math.inf)


def test_scene_name():
    assert scene_name("a/town.scene.json") == "town"
    assert scene_name("town.json") == "town"
    assert scene_name("my.level.json") == "my.level"


# -- errors: one line naming the scene, the object and the problem ---------------------------

GOOD_OBJ = {"model": {"name": "plane.obj"}}
LOD_OBJ = {"model": {"lod": {"final_clamp": 10, "lods": ["monkey/monkey0.obj", "monkey/monkey1.obj"]}}}

ERROR_CASES = [
    # (object, expected fragments)
    ({"model": {"name": "missing.obj"}}, ["object 1", "model.name", "missing.obj", "file not found"]),
    ({"model": {"name": "plane.obj"}, "colour": 1}, ["object 1", "unknown key 'colour'"]),
    ({"model": {"name": "plane.obj", "scale": 2}}, ["object 1: model", "unknown key 'scale'"]),
    ({"model": {"lod": {"lods": ["monkey/monkey0.obj"], "final_clamp": 5, "blend": 1}}},
     ["object 1: model.lod", "unknown key 'blend'"]),
    ({"model": {"name": 3}}, ["object 1: model.name", "must be a file name"]),
    ({"model": {"name": "plane.txt"}}, ["object 1: model.name", "unsupported model file type '.txt'"]),
    ({"model": {}}, ["object 1: model", "needs name"]),
    ({"texture": "monkey/monkey.png"}, ["object 1", "missing key 'model'"]),
    ({"model": {"lod": {"lods": []}}}, ["object 1: model.lod.lods", "at least one model file"]),
    ({"model": {"lod": {"lods": "monkey/monkey0.obj"}}}, ["object 1: model.lod.lods", "at least one"]),
    ({"model": {"lod": {"lods": ["monkey/monkey0.obj", "monkey/monkey9.obj"]}}},
     ["object 1: model.lod.lods[1]", "monkey9.obj", "file not found"]),
    ({"model": {"lod": {"lods": ["monkey/monkey0.obj", "monkey/monkey0.obj"]}}},
     ["object 1: model.lod.lods[1]", "also level 0"]),
    ({"model": {"lod": {"final_clamp": 0, "lods": ["monkey/monkey0.obj"]}}},
     ["object 1: model.lod.final_clamp", "must be > 0"]),
    ({"model": {"lod": {"final_clamp": "far", "lods": ["monkey/monkey0.obj"]}}},
     ["object 1: model.lod.final_clamp", "must be a number"]),
    ({"model": {"name": "plane.obj", "lod": {"lods": ["monkey/monkey0.obj"]}}},
     ["object 1: model", "either name or lod.lods"]),
    ({"model": {"lod": {"generate": True, "lods": ["monkey/monkey0.obj"]}}},
     ["object 1: model.lod", "only applies to a model given by name"]),
    ({"model": {"name": "plane.obj", "lod": {"ratios": [0.5, 0.25]}}},
     ["object 1: model.lod.ratios", "must start with 1"]),
    ({"model": {"name": "plane.obj", "lod": {"ratios": [1, 0.5, 0.5]}}},
     ["object 1: model.lod.ratios[2]", "each level coarser"]),
    ({"model": {"name": "plane.obj", "lod": {"generate": False, "ratios": [1, 0.5]}}},
     ["object 1: model.lod", "ratios given with generate false"]),
    ({"model": {"name": "plane.obj"}, "texture": "monkey/nope.png"},
     ["object 1: texture", "nope.png", "file not found"]),
    ({"model": {"name": "plane.obj"}, "texture": "monkey/monkey.ff"},
     ["object 1: texture", "unsupported texture file type '.ff'"]),
    ({**GOOD_OBJ, "instances": []}, ["object 1: instances", "is empty"]),
    ({**GOOD_OBJ, "instances": {"translation": [1, 2, 3]}}, ["object 1: instances", "must be a list"]),
    ({**GOOD_OBJ, "instances": [[{"translation": [1, 2]}]]},
     ["object 1: instances[0][0].translation", "list of 3 numbers"]),
    ({**GOOD_OBJ, "instances": [[], [{"translation": [1, "x", 3]}]]},
     ["object 1: instances[1][0].translation[1]", "must be a number"]),
    ({**GOOD_OBJ, "instances": [[{"shear": [1, 2, 3]}]]}, ["object 1: instances[0][0]", "unknown transform op 'shear'"]),
    ({**GOOD_OBJ, "instances": [[{"translation": [1, 2, 3], "scaling": [1, 1, 1]}]]},
     ["object 1: instances[0][0]", "exactly one of"]),
    ({**GOOD_OBJ, "instances": [[{"scaling": [1, 0, 1]}]]}, ["object 1: instances[0]", "singular"]),
    ({**GOOD_OBJ, "instances": [[{"scaling": [1e200, 1e200, 1e200]}, {"scaling": [1e200, 1, 1]}]]},
     ["object 1: instances[0]", "not finite"]),
    ({**GOOD_OBJ, "view_distance": [10, 5]}, ["object 1: view_distance", "nearer than near"]),
    ({**GOOD_OBJ, "view_distance": [-1, 5]}, ["object 1: view_distance[0]", "must be >= 0"]),
    ({**GOOD_OBJ, "view_distance": 5}, ["object 1: view_distance", "[near, far]"]),
    ({**GOOD_OBJ, "max_screen_px": -3}, ["object 1: max_screen_px", "must be > 0"]),
    ({**GOOD_OBJ, "light": {"colour": [1, 1, 1]}}, ["object 1: light", "unknown key 'colour'"]),
    ({**GOOD_OBJ, "light": {"color": [1, 1]}}, ["object 1: light.color", "3 or 4 numbers"]),
]


@pytest.mark.parametrize("obj, fragments", ERROR_CASES, ids=[str(i) for i in range(len(ERROR_CASES))])
def test_errors_name_scene_object_and_problem(tmp_path, obj, fragments):
    path = _scene_with(tmp_path, GOOD_OBJ, obj)
    with pytest.raises(SceneError, match=f"^{re.escape(str(path))}: ") as info:
        load_scene(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: ")
    for frag in fragments:
        assert frag in msg, (frag, msg)


@pytest.mark.parametrize("text, fragment", [
    ('{"scene": {"objects": [{"model": {"name": "plane.obj"}}]', "invalid JSON at line 1"),
    ('[1, 2]', "must be an object"),
    ('{"objects": []}', "unknown key 'objects'"),
    ('{"scene": {}}', "scene: missing key 'objects'"),
    ('{"scene": {"objects": {}}}', "scene.objects: must be a list"),
    ('{"scene": {"objects": [], "camera": {}}}', "scene: unknown key 'camera'"),
    ('{"scene": {"objects": [], "ambient_light": [1, NaN, 1]}}', "scene.ambient_light[1]: must be finite"),
    ('{"scene": {"objects": [], "texture_budget": 0}}', "scene.texture_budget: must be a whole number"),
    ('{"scene": {"objects": [], "texture_budget": 10.5}}', "scene.texture_budget"),
    ('{"scene": {"objects": [], "texture_compression": "astc"}}',
     'scene.texture_compression: must be one of none, bc, etc2, not "astc"'),
    ('{"scene": {"objects": [{"model": {"name": "plane.obj"}, "model": {"name": "plane.obj"}}]}}',
     "object 0: duplicate key 'model'"),
    ('{"scene": {"objects": [{"model": {"name": "plane.obj"}, '
     '"instances": [[{"rotationY": Infinity}]]}]}}', "object 0: instances[0][0].rotationY: must be finite"),
])
def test_scene_level_errors(tmp_path, text, fragment):
    _scene_with(tmp_path)
    path = _write(tmp_path, text)
    with pytest.raises(SceneError, match=re.escape(fragment)) as info:
        load_scene(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(f"{path}: ")
    assert fragment in str(info.value)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(tmp_path / "nope.scene.json")


def test_a_folder_is_not_a_file(tmp_path):
    path = _scene_with(tmp_path, {"model": {"name": "monkey"}})
    with pytest.raises(SceneError, match="unsupported model file type"):
        load_scene(path)
    (tmp_path / "dir.obj").mkdir()
    path = _scene_with(tmp_path, {"model": {"name": "dir.obj"}})
    with pytest.raises(SceneError, match="dir.obj: is not a file"):
        load_scene(path)


def test_absolute_and_parent_paths(tmp_path):
    sub = tmp_path / "scenes"
    sub.mkdir()
    crate = (EXAMPLES / "crate" / "crate.gltf").resolve()
    path = _write(sub, {"scene": {"objects": [{"model": {"name": str(crate)}},
                                              {"model": {"name": "../x.obj"}}]}})
    with pytest.raises(SceneError, match=r"object 1: model\.name: \.\./x\.obj: file not found"):
        load_scene(path)
    (tmp_path / "x.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    sc = load_scene(path)
    assert sc.objects[0].model == crate and sc.objects[1].model == (tmp_path / "x.obj").resolve()


# -- transforms ------------------------------------------------------------------------------

def _rot(axis: str, deg: float) -> np.ndarray:
    """Independent reference: Rodrigues' formula for a right-handed rotation."""
    k = {"X": [1, 0, 0], "Y": [0, 1, 0], "Z": [0, 0, 1]}[axis]
    k = np.array(k, dtype=float)
    a = math.radians(deg)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    r = np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * kx @ kx
    m = np.eye(4)
    m[:3, :3] = r
    return m


def _t(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


def _s(v):
    return np.diag([*v, 1.0])


def test_rotation_conventions_right_handed():
    # +90 about Z takes +X to +Y; about X takes +Y to +Z; about Y takes +Z to +X
    assert np.allclose(compose_ops([("rotationZ", 90)]) @ [1, 0, 0, 1], [0, 1, 0, 1])
    assert np.allclose(compose_ops([("rotationX", 90)]) @ [0, 1, 0, 1], [0, 0, 1, 1])
    assert np.allclose(compose_ops([("rotationY", 90)]) @ [0, 0, 1, 1], [1, 0, 0, 1])
    for axis in "XYZ":
        for deg in (0, 30, -45, 90, 180, 270, 360, 725.5):
            assert np.allclose(compose_ops([(f"rotation{axis}", deg)]), _rot(axis, deg), atol=1e-12)


def test_translation_and_scaling():
    assert np.array_equal(compose_ops([("translation", (1, 2, 3))]), _t([1, 2, 3]))
    assert np.array_equal(compose_ops([("scaling", (2, 3, 4))]), _s([2, 3, 4]))


def test_ops_round_trip_against_independent_product(tmp_path):
    rng = np.random.default_rng(7)
    names = ["translation", "scaling", "rotationX", "rotationY", "rotationZ"]
    instances, expected = [], []
    for _ in range(20):
        ops, m = [], np.eye(4)
        for _ in range(rng.integers(0, 6)):
            name = names[rng.integers(len(names))]
            if name == "translation":
                v = [round(float(x), 3) for x in rng.uniform(-50, 50, 3)]
                m = m @ _t(v)
            elif name == "scaling":
                v = [round(float(x), 3) for x in rng.uniform(0.1, 3, 3) * rng.choice([-1, 1], 3)]
                m = m @ _s(v)
            else:
                v = round(float(rng.uniform(-360, 360)), 2)
                m = m @ _rot(name[-1], v)
            ops.append({name: v})
        instances.append(ops)
        expected.append(m)
    path = _scene_with(tmp_path, {**GOOD_OBJ, "instances": instances})
    got = load_scene(path).objects[0].instances
    assert len(got) == 20
    for g, e in zip(got, expected):
        assert np.allclose(g, e, atol=1e-9)
    # and through the output: row-major rows, column vectors (translation in the last column)
    sc = load_scene(path)
    plan = plan_scene([sc])
    out = json.loads(encode_scene_output(sc, {k: {"id": "plane", "switchDistances": [0.0]} for k in plan.models}))
    for inst, e in zip(out["objects"][0]["instances"], expected):
        assert np.allclose(np.array(inst["matrix"]), e, rtol=1e-7, atol=1e-6)
        assert inst["lodScale"] == pytest.approx(np.linalg.svd(e[:3, :3], compute_uv=False)[0], rel=1e-7)


def test_max_stretch():
    assert max_stretch(compose_ops([("rotationY", 33), ("scaling", (0.5, 3, 2))])) == pytest.approx(3)
    assert max_stretch(compose_ops([("scaling", (-2, 1, 1))])) == pytest.approx(2)


# -- level selection -------------------------------------------------------------------------

SW = [0.0, 10.0, 20.0, 40.0]


@pytest.mark.parametrize("near, far, levels", [
    (0, math.inf, [0, 1, 2, 3]),
    (0, 5, [0]),
    (0, 10, [0, 1]),          # level 1 starts at exactly 10
    (0, 9.999, [0]),
    (15, 25, [1, 2]),
    (20, 20, [2]),
    (25, 30, [2]),
    (45, 1000, [3]),
    (10, 40, [1, 2, 3]),
    (0, 0, [0]),
])
def test_select_levels(near, far, levels):
    assert select_levels(SW, near, far) == levels


def test_select_levels_empty_intervals_and_edge_cases():
    # level 1 switches in at the same distance as level 2: never selected
    assert select_levels([0, 10, 10, 30], 0, math.inf) == [0, 2, 3]
    assert select_levels([0, 10, 10, 30], 10, 10) == [2]
    # a single level
    assert select_levels([0.0], 0, math.inf) == [0]
    # a first switch above 0: level 0 still serves nearer distances
    assert select_levels([5, 10], 0, 1) == [0]
    assert level_at([0, 10, 20], 19.9) == 1
    with pytest.raises(ValueError, match=r"not measured \(NaN\)"):
        select_levels([0, float("nan")], 0, 1)
    with pytest.raises(ValueError, match="must not decrease"):
        select_levels([0, 10, 5], 0, 1)
    with pytest.raises(ValueError, match="near 5 is beyond far 1"):
        select_levels([0, 10], 5, 1)
    with pytest.raises(ValueError, match="no LOD levels"):
        select_levels([], 0, 1)


# -- planning --------------------------------------------------------------------------------

def test_plan_unions_across_two_scenes():
    seed, town = load_scene(SCENES / "seed.scene.json"), load_scene(SCENES / "town.scene.json")
    plan = plan_scene([seed, town], LodOptions(), TextureOptions())
    keys = list(plan.models)
    # the hand-made list is one model, shared by both scenes
    lod_key = seed.objects[2].key
    assert lod_key == town.objects[3].key and lod_key in plan.models
    lp = plan.models[lod_key]
    assert [(u.scene, u.object_index) for u in lp.uses] == [("seed", 2), ("town", 3)]
    # farthest: seed clamps at 100, town at 60 -> 100; nearest: seed has no near -> 0
    assert lp.max_lod_distance == 100 and lp.min_lod_distance == 0
    assert lp.needs_uv is True  # the objects give a texture
    # the plane: default LODs in seed, "generate": false in town -> two models
    planes = [k for k in keys if k.sources[0].name == "plane.obj"]
    assert sorted(k.ratios or () for k in planes) == [(), (1.0,)]
    # sources: each file once
    assert len(plan.sources()) == len(set(plan.sources()))
    assert plan.referenced(SCENES / "plane.obj") and plan.referenced(SCENES / "monkey" / "monkey.png")
    assert not plan.referenced(EXAMPLES / "crate" / "crate.png")
    assert plan.unreferenced_reasons([EXAMPLES / "crate" / "crate.png"]) == [
        f"{EXAMPLES / 'crate' / 'crate.png'}: not built: no scene references it"]
    # the seed scene alone: the list's range is only its own
    alone = plan_scene([town])
    assert alone.models[lod_key].max_lod_distance == 60
    assert alone.models[lod_key].min_lod_distance == 10


def test_plan_distances_in_model_units_per_instance_scale():
    town = load_scene(SCENES / "town.scene.json")
    plan = plan_scene([town])
    pyr = plan.models[town.objects[1].key]
    # view [5, 400], final_clamp 200, instances scaled 1 and 2: near 5/2, far 200/1
    assert pyr.min_lod_distance == pytest.approx(2.5)
    assert pyr.max_lod_distance == pytest.approx(200)
    assert pyr.kept_levels([0, 1, 2, 150, 199, 201, 500]) == [2, 3, 4]
    reasons = pyr.level_reasons([0, 1, 2, 150, 199, 201, 500])
    assert any("levels 5, 6 not built" in r and "final_clamp 200" in r for r in reasons)
    assert any("levels 0, 1 not built" in r and "view distance >= 5" in r for r in reasons)
    assert pyr.lod_options_for(LodOptions()).ratios == (1.0, 0.5, 0.25)
    plane_nolod = plan.models[town.objects[0].key]
    assert plane_nolod.lod_options_for().ratios == (1.0,)


def test_plan_screen_size_bounds_nearest_distance_with_radius():
    town = load_scene(SCENES / "town.scene.json")
    plan = plan_scene([town])
    crate = plan.models[town.objects[2].key]
    assert crate.lod_range() == (0.0, math.inf)   # without bounds, nothing is known
    lo, hi = crate.lod_range(radius=2.0)
    assert hi == math.inf
    assert sphere_screen_px(2.0, lo, LodOptions()) == pytest.approx(300)


def test_texture_size_from_screen_size_and_budget():
    opts = LodOptions()
    assert [next_pow2(x) for x in (0.5, 1, 2, 3, 255, 256, 257, 300)] == [1, 1, 2, 4, 256, 256, 512, 512]
    town = load_scene(SCENES / "town.scene.json")
    plan = plan_scene([town], opts, TextureOptions())
    # crate: at most 300 px on screen -> 512, under the budget of 1024
    assert plan.models[town.objects[2].key].texture_max_size == 512
    # pyramid: no screen size known without bounds -> the budget
    pyr = plan.models[town.objects[1].key]
    assert pyr.texture_max_size == 1024
    # with bounds: nearest 2.5 model units, radius 0.1 -> small on screen
    r = 0.1
    px = sphere_screen_px(r, 2.5, opts)
    assert px == pytest.approx(2 * opts.pixels_per_unit_at_unit_distance() * r / math.sqrt(2.5 ** 2 - r ** 2))
    assert pyr.texture_size(radius=r) == next_pow2(px) < 1024
    # camera may be inside the bounds: only the budget limits
    assert pyr.texture_size(radius=10) == 1024
    # the build's --max-texture-size still applies
    small = plan_scene([town], opts, TextureOptions(max_size=256))
    assert small.models[town.objects[2].key].texture_max_size == 256
    assert small.models[town.objects[1].key].texture_options_for().max_size == 256
    # the seed scene has no budget and no sizes: only the build's cap (8192 by default, #13)
    seed = load_scene(SCENES / "seed.scene.json")
    cap = TextureOptions().max_size
    sp = plan_scene([seed])
    assert all(m.texture_max_size == cap for m in sp.models.values())
    assert sp.object_texture_size(SCENES / "monkey" / "monkey.png") == cap
    assert all(m.texture_max_size is None for m in plan_scene([seed], opts, TextureOptions(max_size=None)).models.values())
    # across scenes the larger need wins (the texture is shared)
    both = plan_scene([seed, town])
    assert both.object_texture_size(SCENES / "monkey" / "monkey.png") == cap
    assert plan.object_texture_size(SCENES / "monkey" / "monkey.png") == 1024
    key = town.objects[3].key
    assert plan.object_texture_size(SCENES / "monkey" / "monkey.png", {key: 1.0}) == next_pow2(
        sphere_screen_px(1.0, 10.0, opts))


def test_distance_for_screen_px_inverts_sphere_screen_px():
    opts = LodOptions(resolution_px=720, fov_y_deg=45)
    for r, px in ((1.0, 100.0), (0.3, 7.0), (50.0, 2000.0)):
        assert sphere_screen_px(r, distance_for_screen_px(r, px, opts), opts) == pytest.approx(px)


def test_plan_reasons_are_one_line_each():
    plan = plan_scene([load_scene(SCENES / "seed.scene.json"), load_scene(SCENES / "town.scene.json")])
    assert plan.reasons
    assert all("\n" not in r for r in plan.reasons)
    assert any("final_clamp 100 in scene seed object 2" in r for r in plan.reasons)
    assert any(r.startswith("crate.gltf: textures capped at 512 px") for r in plan.reasons)


def test_plan_duplicate_scene_names(tmp_path):
    a = load_scene(SCENES / "seed.scene.json")
    other = tmp_path / "seed.json"
    other.write_text((SCENES / "seed.scene.json").read_text().replace("./plane.obj", str(SCENES / "plane.obj"))
                     .replace('"monkey/', f'"{SCENES}/monkey/').replace("./sphere.obj", str(SCENES / "sphere.obj")))
    b = load_scene(other)
    with pytest.raises(SceneError, match="also the name of"):
        plan_scene([a, b])


# -- attributes and materials ----------------------------------------------------------------

def _mat(color=(1, 1, 1, 1), textures=None, alpha="OPAQUE"):
    return {"name": "m", "baseColorFactor": list(color), "alphaMode": alpha, "alphaCutoff": 0.5,
            "doubleSided": False, "metallicFactor": 1.0, "roughnessFactor": 1.0,
            "emissiveFactor": [0, 0, 0], "textures": textures or {}}


def _tex(image=0, tex_coord=0):
    return {"image": image, "texCoord": tex_coord, "sampler": {}}


def test_attributes_needed():
    full = ("position", "uv0", "normal", "tangent", "uv1", "color")
    assert attributes_needed([_mat()]) == ("position",)
    assert attributes_needed([_mat()], object_texture=True) == ("position", "uv0")
    assert attributes_needed([_mat(), _mat(textures={"baseColor": _tex()})]) == ("position", "uv0")
    assert attributes_needed([_mat()], full) == ("position", "normal", "color")
    assert attributes_needed([_mat(textures={"baseColor": _tex(), "normal": _tex(1, 0)})], full) == (
        "position", "uv0", "normal", "tangent", "color")
    assert attributes_needed([_mat(textures={"occlusion": _tex(0, 1)})], full) == (
        "position", "normal", "uv1", "color")
    assert attributes_needed([]) == ("position",)
    reasons = attribute_reasons("plane.obj", full, ("position", "normal", "color"))
    assert reasons == ["plane.obj: uv0 not computed (no material samples a texture with UV set 0)",
                       "plane.obj: tangent not computed (no material has a normal map)",
                       "plane.obj: uv1 not computed (no material samples UV set 1)"]


def test_attributes_needed_on_imported_example():
    """The import step's material dicts, as task_import records them."""
    from assetpipe.pipelines.import_obj import import_obj

    model = import_obj(EXAMPLES / "pyramid" / "pyramid.obj")
    mats = [{"baseColorFactor": list(m.base_color_factor), "alphaMode": m.alpha_mode,
             "textures": {role: {"image": 0, "texCoord": ref.tex_coord} for role, ref in m.textures().items()}}
            for m in model.materials]
    assert attributes_needed(mats) == ("position", "uv0")
    assert attributes_needed(mats, ("position", "uv0", "normal", "tangent")) == ("position", "uv0", "normal")


def test_check_shared_materials():
    images = [{"name": "a", "digest": "xxh3:aa", "path": "a.png"}]
    lod0 = {"materials": [_mat(textures={"baseColor": _tex(0)}), _mat((1, 0, 0, 1))],
            "images": images, "meshMaterials": [0, 1]}
    assert check_shared_materials([lod0]) == []
    same = copy.deepcopy(lod0)
    same["images"] = [{"name": "a2", "digest": "xxh3:aa", "path": "elsewhere/a.png"}]  # same content
    same["meshMaterials"] = [1]  # a coarse level may drop a part
    assert check_shared_materials([lod0, same]) == []

    other_image = copy.deepcopy(lod0)
    other_image["images"] = [{"name": "b", "digest": "xxh3:bb", "path": "a.png"}]
    assert check_shared_materials([lod0, other_image], ["m0.obj", "m1.obj"]) == [
        "m1.obj: material 0 baseColor texture differs from m0.obj's"]

    fewer = {"materials": [lod0["materials"][0]], "images": images}
    colour = copy.deepcopy(lod0)
    colour["materials"][1]["baseColorFactor"] = [0, 1, 0, 1]
    untextured = copy.deepcopy(lod0)
    untextured["materials"][0]["textures"] = {}
    extra_use = copy.deepcopy(lod0)
    extra_use["meshMaterials"] = [0, 1, 2]
    problems = check_shared_materials([lod0, fewer, colour, untextured, extra_use])
    assert problems == [
        "LOD1: 1 materials, LOD0 has 2",
        "LOD2: material 1 base colour [0, 1, 0, 1] differs from LOD0's [1, 0, 0, 1]",
        "LOD3: material 0 baseColor texture: LOD0 has one, LOD3 does not",
        "LOD4: meshes use material(s) 2, which LOD0's meshes do not",
    ]
    # plain material lists work too (textures compared by image index then)
    assert check_shared_materials([lod0["materials"], lod0["materials"]]) == []
    alpha = copy.deepcopy(lod0["materials"])
    alpha[0]["alphaMode"] = "BLEND"
    assert check_shared_materials([lod0["materials"], alpha]) == [
        "LOD1: material 0 alpha mode BLEND differs from LOD0's OPAQUE"]


def test_handmade_fixture_lists_share_materials():
    """The fixture's hand-made list, imported as the build would (no MTL: default material)."""
    from assetpipe.pipelines.import_obj import import_obj

    metas = []
    for p in load_scene(SCENES / "seed.scene.json").objects[2].lod_files:
        model = import_obj(p)
        metas.append({"materials": [{"baseColorFactor": list(m.base_color_factor), "alphaMode": m.alpha_mode,
                                     "textures": {}} for m in model.materials],
                      "images": [], "meshMaterials": [m.material for m in model.meshes]})
    assert check_shared_materials(metas) == []


# -- output ----------------------------------------------------------------------------------

def _models_for(plan, switches=(0.0, 2.5, 30.0)):
    out = {}
    for i, key in enumerate(sorted(plan.models, key=ModelKey.sort_key)):
        out[key] = {"id": f"{key.sources[0].stem}-{i}", "switchDistances": list(switches),
                    "bounds": {"center": [0.0, 0.0, 0.0], "radius": 1.0}}
    return out


def test_encode_scene_output():
    seed = load_scene(SCENES / "seed.scene.json")
    plan = plan_scene([seed])
    models = _models_for(plan, (0.5, 2.5, 30.0))
    tex = {seed.objects[2].texture: {"path": "textures/xxh3-1.png", "ktx2": "textures/xxh3-1-baseColor.ktx2"}}
    data = encode_scene_output(seed, models, tex)
    assert data == encode_scene_output(seed, models, tex)  # deterministic
    assert data.endswith(b"\n")
    out = json.loads(data)
    assert out["formatVersion"] == 1 and out["scene"] == "seed"
    assert out["ambientLight"] == [1.0, 1.0, 1.0, 0.2]
    assert [m["id"] for m in out["models"]] == sorted(m["id"] for m in out["models"])
    assert all(m["file"] == m["id"] + ".json" for m in out["models"])
    ids = {k: v["id"] for k, v in models.items()}
    objs = out["objects"]
    assert [o["index"] for o in objs] == [0, 1, 2]
    assert [o["model"] for o in objs] == [ids[o.key] for o in seed.objects]
    assert objs[1]["light"] == {"color": [1.0, 1.0, 1.0, 1.0]}
    assert objs[2]["texture"] == tex[seed.objects[2].texture]
    assert objs[2]["lod"] == {"finalClamp": 100.0, "switchDistances": [0.0, 2.5, 30.0]}  # first is 0
    assert objs[0]["lod"]["finalClamp"] is None
    assert objs[1]["instances"] == [{"matrix": [[0.1, 0.0, 0.0, 10.0], [0.0, 0.1, 0.0, -40.0],
                                                [0.0, 0.0, 0.1, 15.0], [0.0, 0.0, 0.0, 1.0]],
                                     "lodScale": 0.1}]
    assert objs[2]["instances"][0]["matrix"] == [[1.0, 0.0, 0.0, 1.0], [0.0, -1.0, 0.0, -1.0],
                                                 [0.0, 0.0, -1.0, -1.0], [0.0, 0.0, 0.0, 1.0]]
    # readable: number lists on one line
    assert b'"switchDistances": [0.0, 2.5, 30.0]' in data


def test_encode_scene_output_extensions_and_missing_inputs():
    town = load_scene(SCENES / "town.scene.json")
    plan = plan_scene([town])
    models = _models_for(plan)
    tex = {town.objects[3].texture: {"path": "textures/m.png"}}
    out = json.loads(encode_scene_output(town, models, tex))
    assert out["textureBudget"] == 1024
    assert out["objects"][1]["viewDistance"] == [5.0, 400.0]
    assert out["objects"][3]["viewDistance"] == [10.0, None]
    assert out["objects"][2]["maxScreenPx"] == 300.0
    assert out["objects"][1]["instances"][1]["lodScale"] == 2.0
    with pytest.raises(KeyError, match="no built texture"):
        encode_scene_output(town, models, {})
    del models[town.objects[0].key]
    with pytest.raises(KeyError, match="object 0: no built model"):
        encode_scene_output(town, models, tex)


# -- corpus: the import step's real material records ----------------------------------------

@pytest.mark.corpus
def test_attributes_and_plan_on_corpus_models(corpus, tmp_path):
    from assetpipe.steps import task_import

    full = ("position", "uv0", "normal", "tangent", "uv1", "color")
    want = {"Duck": ("position", "uv0", "normal", "color"),
            "Avocado": ("position", "uv0", "normal", "tangent", "color"),
            "MultiUVTest": ("position", "uv0", "normal", "uv1", "color")}
    objects = []
    for name, expected in want.items():
        src = corpus / "models" / name / "glTF" / f"{name}.gltf"
        meta = task_import(str(tmp_path / "store"), str(src))["meta"]
        assert attributes_needed(meta["materials"], full) == expected, name
        # a model shares materials with itself, images compared by content digest
        assert check_shared_materials([meta, meta]) == []
        objects.append({"model": {"name": str(src)}, "max_screen_px": 100})
    path = _write(tmp_path, {"scene": {"objects": objects, "texture_budget": 64}})
    plan = plan_scene([load_scene(path)])
    assert len(plan.models) == 3
    assert all(m.texture_max_size == 64 for m in plan.models.values())
