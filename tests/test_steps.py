"""assetpipe/steps.py: what the step keys hold beyond inputs and options."""

from assetpipe.pipelines.texture_compress import etcpak_variant
from assetpipe.steps import texture_key_libs


def test_etc2_texture_keys_name_the_etcpak_build_that_encodes_them():
    libs = {"etcpak": "0.9.15", "numpy": "2.0"}
    etc2 = texture_key_libs(libs, {"compression": "etc2", "supercompression": "none"})
    # the build that really runs here (its blocks differ from the other builds')
    assert etc2 == {**libs, "etcpak-build": etcpak_variant()}
    assert etcpak_variant() in ("avx512", "avx2", "sse41", "neon", "none")
    # BC and RGBA8 do not depend on the CPU: their keys stay shareable across machines
    assert texture_key_libs(libs, {"compression": "bc"}) == libs
    assert texture_key_libs(libs, {"compression": "none"}) == libs
    assert texture_key_libs(libs, None) == libs
    assert "etcpak-build" not in libs  # the caller's dict is not changed


def test_texture_keys_leave_out_the_lod_steps_wasm_simplifier():
    """Installing or removing meshoptimizer's WASM simplifier (the LOD step's alone) must not
    rebuild textures: the texture key holds every other library and not that one."""
    libs = {"numpy": "2.0", "pillow": "11", "meshoptimizer-wasm": "1.3.0"}
    for opts in (None, {"compression": "bc"}, {"compression": "etc2"}):
        key_libs = texture_key_libs(libs, opts)
        assert "meshoptimizer-wasm" not in key_libs and key_libs["numpy"] == "2.0"
        assert texture_key_libs({**libs, "meshoptimizer-wasm": None}, opts) == key_libs
    assert libs["meshoptimizer-wasm"] == "1.3.0"  # the caller's dict is not changed


def test_a_scene_that_drops_lod0_keeps_only_the_rows_its_levels_use():
    """Kept levels (LOD0 dropped): the prefix the levels over LOD0's vertices use, then each
    moved level's own rows moved down behind it; every level draws the same triangles."""
    import numpy as np

    from assetpipe.format import OutputLod
    from assetpipe.steps import _kept_rows

    rows = np.arange(40 * 5, dtype=np.float32).reshape(40, 5)  # LOD0 0..19, level 2 own 20..29, level 3 own 30..39
    plain = OutputLod(indices=np.array([[0, 1, 2], [2, 3, 0]], np.uint32), vertex_count=4)
    moved = OutputLod(indices=np.array([[30, 31, 32], [33, 30, 32]], np.uint32), vertex_count=34, vertex_start=30)
    vertices, lods = _kept_rows(rows, (plain, moved))
    assert vertices.shape == (8, 5) and lods[0].vertex_count == 4
    assert (lods[1].vertex_start, lods[1].vertex_count) == (4, 8)
    for before, after in zip((plain, moved), lods):
        assert np.array_equal(rows[before.indices], vertices[after.indices])
    # only moved levels kept: their rows alone, the first starting at 0 (a prefix then)
    vertices, lods = _kept_rows(rows, (moved,))
    assert vertices.shape == (4, 5) and (lods[0].vertex_start, lods[0].vertex_count) == (0, 4)
    assert np.array_equal(rows[moved.indices], vertices[lods[0].indices])


def test_materials_equal_in_content_share_a_lod_group():
    """Names do not matter, everything else does; a mesh without a valid material keeps its
    index (so it is never merged with a real one)."""
    from assetpipe.steps import material_groups

    def mat(name, colour=(1, 1, 1, 1), image=None, tex_coord=0):
        tex = {} if image is None else {"baseColor": {"image": image, "texCoord": tex_coord, "sampler": {}}}
        return {"name": name, "baseColorFactor": list(colour), "alphaMode": "OPAQUE", "alphaCutoff": 0.5,
                "doubleSided": False, "metallicFactor": 1.0, "roughnessFactor": 1.0,
                "emissiveFactor": [0, 0, 0], "textures": tex}

    mats = [mat("steel"), mat("steel.001"), mat("red", (1, 0, 0, 1)), mat("wood", image=0),
            mat("wood.001", image=0), mat("wood-uv1", image=0, tex_coord=1), mat("oak", image=1)]
    assert material_groups(mats, [0, 1, 2, 3, 4, 5, 6, -1, 1]) == [0, 0, 2, 3, 3, 5, 6, -1, 0]


def test_meshes_with_materials_equal_in_content_are_merged_for_lod(corpus, tmp_path):
    """2CylinderEngine's 34 materials are 7 by content: its LOD meshes are merged into 7, as
    gltfpack merges them (docs/BUILD.md)."""
    import json

    from assetpipe.build import run_build
    from assetpipe.options import DEFAULT_BUILD_OPTIONS

    src = corpus / "models/2CylinderEngine/glTF/2CylinderEngine.gltf"
    r = run_build([src], tmp_path / "out", DEFAULT_BUILD_OPTIONS, cache_dir=tmp_path / "cache")
    assert not r.failed
    side = json.loads((tmp_path / "out/2CylinderEngine.asset.json").read_text())
    assert len(side["meshes"]) == 7 and len(side["materials"]) == 34


def test_an_image_with_uses_sharing_a_chain_stores_each_blob_once(tmp_path, monkeypatch):
    """An ORM image used as occlusion and metallicRoughness (one chain) and kept as its own
    bytes for level 0: task_texture_uses puts each distinct blob once (not once per use: each
    put hashes it, and a blob found stored is read back and hashed again), and each use's record
    is the one task_texture makes of it alone."""
    import io

    import numpy as np
    from PIL import Image

    from assetpipe.cache.store import Store
    from assetpipe.core.hashing import digest_bytes
    from assetpipe.steps import task_texture, task_texture_uses, texture_use_record

    rgb = (np.random.default_rng(3).random((64, 64, 3)) * 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    (tmp_path / "orm.png").write_bytes(buf.getvalue())
    image = {"path": "orm.png", "name": "orm.png", "mime": "image/png", "digest": digest_bytes(buf.getvalue())}
    uses = [["occlusion", "OPAQUE", 0.5], ["metallicRoughness", "OPAQUE", 0.5]]
    store_root = str(tmp_path / "cache")
    Store(tmp_path / "cache")
    puts = []
    real = Store.put_blob

    def counting(self, data):
        puts.append(len(data))
        return real(self, data)

    monkeypatch.setattr(Store, "put_blob", counting)
    rec = task_texture_uses(store_root, image, str(tmp_path), uses, {})
    assert len(puts) == 2  # the one chain's KTX2 and the image's own bytes for level 0
    monkeypatch.setattr(Store, "put_blob", real)
    for i, (role, alpha, cutoff) in enumerate(uses):
        assert texture_use_record(rec, i) == task_texture(store_root, image, str(tmp_path), role, alpha, cutoff, {})
