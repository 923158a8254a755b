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
