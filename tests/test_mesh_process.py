"""Mesh processing: weld, degenerates, normals, tangents, order optimisation, UV sets, layouts."""

from __future__ import annotations

import numpy as np
import pytest

from assetpipe.pipelines.mesh_options import MeshOptions
from assetpipe.pipelines.mesh_process import (
    compact, optimize_order, process_mesh, smooth_normals, tangents_from_uv, weld_vertices)
from assetpipe.pipelines.model import MeshData

NO_OPT = MeshOptions(optimize=False)


def _mesh(pos, tris, **kw) -> MeshData:
    return MeshData(name=kw.pop("name", "m"), positions=np.asarray(pos, np.float64),
                    indices=np.asarray(tris, np.uint32).reshape(-1, 3), **kw)


def _uv_sphere(n_lon: int = 48, n_lat: int = 24, r: float = 2.0):
    """A UV sphere with a UV seam (duplicated vertices at lon 0 / 360) and single pole vertices."""
    from robust_models import uv_sphere

    return uv_sphere(n_lon, n_lat, r)


def _tri_set(vertices: np.ndarray, tris: np.ndarray) -> set:
    """Triangles as position triples, rotated to a canonical start (winding kept), compared as
    the float32 values the output stores."""
    out = set()
    for t in tris:
        p = [tuple(vertices[i, :3].astype(np.float32).tolist()) for i in t]
        k = min(range(3), key=lambda q: p[q])
        out.add(tuple(p[k:] + p[:k]))
    return out


# -- weld ------------------------------------------------------------------------------------

def test_weld_joins_bit_identical_rows_in_first_occurrence_order():
    v = np.array([[5.0, 0, 0], [1, 0, 0], [5, 0, 0], [3, 0, 0], [1, 0, 0]])
    tris = np.array([[0, 1, 3], [2, 4, 3]], np.uint32)
    out, t, welded = weld_vertices(v, tris)
    assert welded == 2
    np.testing.assert_array_equal(out, [[5, 0, 0], [1, 0, 0], [3, 0, 0]])
    np.testing.assert_array_equal(t, [[0, 1, 2], [0, 1, 2]])
    assert t.dtype == np.uint32


def test_weld_matches_a_sort_of_the_rows_on_random_vertex_buffers():
    """meshoptimizer's hash weld gives what ``np.unique`` over the rows' bytes gave: the first
    vertex of each set of bit-identical rows, in first-occurrence order, and the triangles over
    them (NaN rows with the same bits join, -0.0 joins 0.0)."""
    rng = np.random.default_rng(3)
    for t in range(60):
        n = int(rng.integers(1, 2000))
        pool = rng.standard_normal((max(1, n // 3), int(rng.integers(3, 9)))).astype(np.float32)
        verts = pool[rng.integers(0, pool.shape[0], n)]
        verts[rng.integers(0, n, 3)] = -0.0
        if t % 3 == 0:
            verts[rng.integers(0, n, 2), 0] = np.nan
        tris = rng.integers(0, n, (int(rng.integers(1, 1500)), 3))
        v = np.where(verts == 0.0, 0.0, verts)
        rows = np.ascontiguousarray(v).view(np.dtype((np.void, v.dtype.itemsize * v.shape[1]))).reshape(n)
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        out, t2, welded = weld_vertices(verts, tris)
        np.testing.assert_array_equal(out, verts[first[order]])
        np.testing.assert_array_equal(t2, rank[inverse.reshape(-1)][tris])
        assert t2.dtype == np.uint32 and welded == n - order.size


def test_weld_treats_negative_zero_as_zero_and_keeps_near_equal_apart():
    v = np.array([[0.0, 1, 0], [-0.0, 1, 0], [0.0, 1, np.nextafter(0.0, 1.0)], [0.0, 1, -0.0]])
    out, t, welded = weld_vertices(v, np.array([[0, 1, 2], [3, 2, 1]], np.uint32))
    assert welded == 2
    assert out.shape == (2, 3)
    np.testing.assert_array_equal(t, [[0, 0, 1], [0, 1, 0]])


def test_weld_compares_every_kept_attribute():
    pos = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]]
    tris = [[0, 1, 2], [3, 4, 5]]
    same = process_mesh(_mesh(pos, tris, uv0=np.zeros((6, 2), np.float32)), NO_OPT)
    assert same.welded == 3 and same.vertices.shape == (3, 5)
    uv = np.zeros((6, 2), np.float32)
    uv[3:, 0] = 0.5  # a UV seam: same positions, other UVs
    seam = process_mesh(_mesh(pos, tris, uv0=uv), NO_OPT)
    assert seam.welded == 0 and seam.vertices.shape == (6, 5)
    off = process_mesh(_mesh(pos, tris, uv0=np.zeros((6, 2), np.float32)), MeshOptions(weld=False, optimize=False))
    assert off.welded == 0 and off.vertices.shape == (6, 5)


# -- degenerate triangles --------------------------------------------------------------------

def test_doubled_areas_are_the_cross_and_einsum_values_bit_for_bit():
    """The degenerate test's areas, computed without np.cross's temporaries, are the values it
    computed before, from tiny to huge coordinates and on flat meshes (exactly zero areas)."""
    from assetpipe.pipelines.mesh_process import _doubled_areas

    rng = np.random.default_rng(4)
    for t in range(120):
        n = int(rng.integers(3, 1500))
        scale = 10.0 ** rng.uniform(-6, 8)
        pos = (rng.standard_normal((n, 3)) * scale).astype(np.float32).astype(np.float64)
        if t % 4 == 0:
            pos[:, 2] = pos[:, 0] * 0.5
        tris = rng.integers(0, n, (int(rng.integers(1, 2000)), 3))
        local = pos - pos.mean(axis=0)
        a, b, c = local[tris[:, 0]], local[tris[:, 1]], local[tris[:, 2]]
        cross = np.cross(b - a, c - a)
        assert np.array_equal(_doubled_areas(local, tris), np.sqrt(np.einsum("ij,ij->i", cross, cross))), t


def test_degenerates_dropped_and_counted_but_a_thin_sliver_is_kept():
    pos = [[0, 0, 0], [1, 0, 0], [0, 1, 0],  # a real triangle (sets the mesh size ~1)
           [2, 0, 0], [3, 0, 0], [4, 0, 0],  # collinear: zero area, distinct indices
           [0, 2, 0], [1, 2, 1e-6], [2, 2, 0]]  # a 2 x 1e-6 sliver: thin but real
    tris = [[0, 1, 2], [0, 0, 1], [1, 2, 2], [3, 4, 5], [6, 7, 8], [4, 4, 4]]
    pm = process_mesh(_mesh(pos, tris), NO_OPT)
    assert pm.degenerate_dropped == 4
    got = _tri_set(pm.vertices, pm.indices)
    want = _tri_set(np.array(pos, float), np.array([[0, 1, 2], [6, 7, 8]]))
    assert got == want
    # the collinear vertices are no longer referenced: compacted away
    assert pm.vertices.shape[0] == 6

    kept = process_mesh(_mesh(pos, tris), MeshOptions(drop_degenerate=False, optimize=False))
    assert kept.degenerate_dropped == 0 and kept.indices.shape[0] == 6


def test_degenerate_tolerance_is_relative_to_mesh_size():
    # the same shape at a scale of 1e-6 and 1e6: the sliver survives both, the flat one neither
    for s in (1e-6, 1.0, 1e6):
        pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 3, 0], [1, 3, 1e-5], [2, 3, 0],
                        [0, 5, 0], [1, 5, 0], [3, 5, 0]], float) * s
        pm = process_mesh(_mesh(pos, [[0, 1, 2], [3, 4, 5], [6, 7, 8]]), NO_OPT)
        assert pm.degenerate_dropped == 1, s
        assert pm.indices.shape[0] == 2


# -- smooth normals --------------------------------------------------------------------------

def test_smooth_normals_match_an_analytic_sphere_and_are_shared_across_the_seam():
    pos, tris, uv = _uv_sphere()
    n = smooth_normals(pos, tris)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    exact = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n, exact), -1, 1)))
    assert angle.max() < 1.5 and np.median(angle) < 0.3, (angle.max(), np.median(angle))
    # area weighting is first-order accurate: twice the resolution, about half the error
    pos2, tris2, _ = _uv_sphere(96, 48)
    n2 = smooth_normals(pos2, tris2)
    exact2 = pos2 / np.linalg.norm(pos2, axis=1, keepdims=True)
    angle2 = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n2, exact2), -1, 1)))
    assert angle2.max() < 0.55 * angle.max()
    # seam: vertex i=0 and i=n_lon of a ring share a position and must get the same normal
    w = 49
    for j in range(23):
        np.testing.assert_array_equal(n[j * w], n[j * w + 48])


def test_smooth_normals_are_area_weighted():
    # a vertex shared by a big triangle in the xy plane (normal +z, area 2) and a small one
    # in the xz plane (normal -y, area 0.125)
    pos = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0, 0], [0, 0, 0.5]], float)
    tris = np.array([[0, 1, 2], [0, 3, 4]], np.uint32)
    n = smooth_normals(pos, tris)
    want = np.array([0.0, -0.25, 4.0])  # sum of the cross products (2 x area each)
    np.testing.assert_allclose(n[0], want / np.linalg.norm(want), atol=1e-12)
    np.testing.assert_allclose(n[1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(n[4], [0, -1, 0], atol=1e-12)


def test_generated_normals_in_layout_are_unit_and_outward():
    pos, tris, uv = _uv_sphere(16, 8)
    pm = process_mesh(_mesh(pos, tris, uv0=uv), MeshOptions(layout=("position", "normal")))
    p, n = pm.vertices[:, :3], pm.vertices[:, 3:6]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert (np.einsum("ij,ij->i", n, p / np.linalg.norm(p, axis=1, keepdims=True)) > 0.98).all()


# -- tangents --------------------------------------------------------------------------------

def _quad(mirror: bool):
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    uv = pos[:, :2].astype(np.float32).copy()
    if mirror:
        uv[:, 0] = 1 - uv[:, 0]
    return pos, np.array([[0, 1, 2], [1, 3, 2]], np.uint32), uv


@pytest.mark.parametrize("mirror, t_want, w_want", [(False, [1, 0, 0], 1.0), (True, [-1, 0, 0], -1.0)])
def test_tangent_direction_and_handedness_flip_with_mirrored_uvs(mirror, t_want, w_want):
    pos, tris, uv = _quad(mirror)
    t = tangents_from_uv(pos, tris, np.tile([0.0, 0, 1], (4, 1)), uv)
    np.testing.assert_allclose(t[:, :3], np.tile(t_want, (4, 1)), atol=1e-12)
    np.testing.assert_array_equal(t[:, 3], w_want)


def test_tangents_orthogonal_to_normals_on_a_sphere():
    pos, tris, uv = _uv_sphere(32, 16)
    layout = ("position", "uv0", "normal", "tangent")
    pm = process_mesh(_mesh(pos, tris, uv0=uv), MeshOptions(layout=layout))
    n, t = pm.vertices[:, 5:8], pm.vertices[:, 8:12]
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-9)
    assert np.abs(np.einsum("ij,ij->i", n, t[:, :3])).max() < 1e-9
    assert set(np.unique(t[:, 3])) <= {-1.0, 1.0}
    # u grows with longitude: away from the poles the tangent points along +phi
    p = pm.vertices[:, :3]
    ring = np.abs(p[:, 2]) < 1.5
    phi_dir = np.stack([-p[:, 1], p[:, 0], np.zeros(len(p))], axis=1)
    phi_dir /= np.maximum(np.linalg.norm(phi_dir, axis=1, keepdims=True), 1e-30)
    assert (np.einsum("ij,ij->i", t[ring, :3], phi_dir[ring]) > 0.99).all()


def test_tangents_without_uvs_warn_and_stay_orthonormal():
    pos, tris, _ = _quad(False)
    pm = process_mesh(_mesh(pos, tris), MeshOptions(layout=("position", "normal", "tangent")))
    assert any("tangents requested without UVs" in w for w in pm.warnings)
    n, t = pm.vertices[:, 3:6], pm.vertices[:, 6:9]
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-12)
    assert np.abs(np.einsum("ij,ij->i", n, t)).max() < 1e-12


# -- vertex cache / fetch optimisation -------------------------------------------------------

def test_optimisation_preserves_the_triangle_set_and_compacts():
    pos, tris, uv = _uv_sphere(24, 12)
    # add vertices no triangle references: they must not survive
    extra = np.array([[9.0, 9, 9], [8, 8, 8]])
    pos2 = np.vstack([extra, pos])
    uv2 = np.vstack([np.zeros((2, 2), np.float32), uv])
    tris2 = tris + 2
    pm = process_mesh(_mesh(pos2, tris2, uv0=uv2))
    assert pm.vertices.shape[0] == pos.shape[0]
    assert pm.indices.dtype == np.uint32 and int(pm.indices.max()) == pm.vertices.shape[0] - 1
    assert _tri_set(pm.vertices, pm.indices) == _tri_set(pos, tris)
    assert not np.any(np.all(pm.vertices[:, :3] >= 8, axis=1))
    # fetch order: vertices appear in the order the index buffer first uses them
    first_use = list(dict.fromkeys(pm.indices.reshape(-1).tolist()))
    assert first_use == list(range(pm.vertices.shape[0]))


def test_optimize_order_and_compact_directly():
    v = np.arange(18, dtype=float).reshape(6, 3)
    tris = np.array([[5, 3, 1], [1, 3, 4]], np.uint32)
    out, t = optimize_order(v, tris)
    assert out.shape == (4, 3)
    assert _tri_set(out, t) == _tri_set(v, tris)
    out2, t2 = compact(v, tris)
    np.testing.assert_array_equal(out2, v[[1, 3, 4, 5]])  # order kept
    assert _tri_set(out2, t2) == _tri_set(v, tris)


def test_empty_mesh_and_all_degenerate_mesh():
    empty = process_mesh(_mesh(np.zeros((0, 3)), np.zeros((0, 3))))
    assert empty.vertices.shape == (0, 5) and empty.indices.shape == (0, 3)
    flat = process_mesh(_mesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]))
    assert flat.degenerate_dropped == 1
    assert flat.indices.shape[0] == 0 and flat.vertices.shape[0] == 0


# -- attributes: UV sets, non-finite values, layouts -----------------------------------------

def test_uv_set_1_goes_into_the_uv0_slot():
    pos, tris, _ = _quad(False)
    t0 = np.full((4, 2), 0.25, np.float32)
    t1 = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float32)
    mesh = _mesh(pos, tris, uv0=t0, uv1=t1)
    layout = MeshOptions(layout=("position", "uv0", "uv1"), optimize=False)
    pm = process_mesh(mesh, layout, uv_set=1)
    np.testing.assert_array_equal(pm.vertices[:, 3:5], t1)
    np.testing.assert_array_equal(pm.vertices[:, 5:7], t0)
    pm0 = process_mesh(mesh, layout, uv_set=0)
    np.testing.assert_array_equal(pm0.vertices[:, 3:5], t0)
    np.testing.assert_array_equal(pm0.vertices[:, 5:7], t1)
    # a mesh without TEXCOORD_1 keeps its TEXCOORD_0
    only0 = process_mesh(_mesh(pos, tris, uv0=t1), NO_OPT, uv_set=1)
    np.testing.assert_array_equal(only0.vertices[:, 3:5], t1)


def test_missing_uvs_are_zero_filled():
    pos, tris, _ = _quad(False)
    pm = process_mesh(_mesh(pos, tris), NO_OPT)
    assert pm.vertices.shape == (4, 5)
    np.testing.assert_array_equal(pm.vertices[:, 3:], 0.0)
    assert pm.warnings == ()


def test_non_finite_uvs_replaced_with_a_warning():
    pos, tris, uv = _quad(False)
    uv[2] = [np.nan, 1.0]
    uv[3] = [np.inf, -np.inf]
    pm = process_mesh(_mesh(pos, tris, uv0=uv), NO_OPT)
    assert np.isfinite(pm.vertices).all()
    np.testing.assert_array_equal(pm.vertices[2, 3:5], [0.0, 1.0])
    np.testing.assert_array_equal(pm.vertices[3, 3:5], [0.0, 0.0])
    assert pm.warnings == ("m: 2 non-finite uv0 values replaced by 0",)


def test_non_finite_uvs_do_not_spoil_generated_tangents():
    # the NaN UV is sanitised before the tangents are derived from the UVs
    pos, tris, uv = _quad(False)
    uv[0] = [np.nan, np.nan]
    clean = uv.copy()
    clean[0] = [0, 0]  # what the NaN is replaced by (and what the quad had anyway)
    layout = MeshOptions(layout=("position", "uv0", "normal", "tangent"), optimize=False)
    pm = process_mesh(_mesh(pos, tris, uv0=uv), layout)
    want = process_mesh(_mesh(pos, tris, uv0=clean), layout)
    np.testing.assert_array_equal(pm.vertices, want.vertices)
    # MikkTSpace in glTF handedness: bitangent cross(n, t) * w = -dP/dV (a normal map's green runs up)
    np.testing.assert_allclose(pm.vertices[:, 8:12], np.tile([1.0, 0, 0, -1], (4, 1)), atol=1e-12)
    assert len(pm.warnings) == 1 and "uv0" in pm.warnings[0]


@pytest.mark.parametrize("layout", [("uv0", "position"), ("position", "uvw"), (), ("normal",)])
def test_layout_validation(layout):
    with pytest.raises(ValueError, match="layout must start with 'position'"):
        MeshOptions(layout=layout)


def test_layout_column_order_and_provided_attributes():
    pos, tris, uv = _quad(False)
    normals = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    colors = np.tile(np.array([0.1, 0.2, 0.3, 0.4], np.float32), (4, 1))
    opts = MeshOptions(layout=("position", "color", "normal", "uv0"), optimize=False)
    assert opts.stride == 4 * (3 + 4 + 3 + 2)
    pm = process_mesh(_mesh(pos, tris, uv0=uv, normals=normals, colors=colors), opts)
    assert pm.vertices.shape == (4, 12) and pm.vertices.dtype == np.float64
    np.testing.assert_array_equal(pm.positions, pos)
    np.testing.assert_array_equal(pm.vertices[:, 3:7], colors.astype(np.float64))
    np.testing.assert_array_equal(pm.vertices[:, 7:10], normals)
    np.testing.assert_array_equal(pm.vertices[:, 10:12], uv)
    # a missing colour is white, a missing uv1 zero
    pm2 = process_mesh(_mesh(pos, tris), MeshOptions(layout=("position", "color", "uv1"), optimize=False))
    np.testing.assert_array_equal(pm2.vertices[:, 3:7], 1.0)
    np.testing.assert_array_equal(pm2.vertices[:, 7:9], 0.0)


def test_processing_is_deterministic_and_leaves_its_input_alone():
    pos, tris, uv = _uv_sphere(16, 8)
    mesh = _mesh(pos, tris, uv0=uv)
    before = (pos.copy(), mesh.indices.copy(), uv.copy())
    a = process_mesh(mesh, MeshOptions(layout=("position", "uv0", "normal", "tangent")))
    b = process_mesh(mesh, MeshOptions(layout=("position", "uv0", "normal", "tangent")))
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.indices.tobytes() == b.indices.tobytes()
    np.testing.assert_array_equal(mesh.positions, before[0])
    np.testing.assert_array_equal(mesh.indices, before[1])
    np.testing.assert_array_equal(mesh.uv0, before[2])


def test_layout_with_a_repeated_attribute_is_refused():
    with pytest.raises(ValueError, match='layout names an attribute twice'):
        MeshOptions(layout=("position", "uv0", "uv0"))


def test_real_model_duck(corpus):
    """The Duck: welding finds its shared vertices, optimisation keeps every triangle."""
    from assetpipe.pipelines.import_gltf import import_gltf

    (mesh,) = import_gltf(corpus / "models" / "Duck" / "glTF" / "Duck.gltf").meshes
    layout = MeshOptions(layout=("position", "uv0", "normal", "tangent"))
    pm = process_mesh(mesh, layout)
    assert pm.degenerate_dropped == 0 and pm.warnings == ()
    assert pm.indices.shape == mesh.indices.shape
    assert pm.vertices.shape[0] == mesh.positions.shape[0] - pm.welded
    assert _tri_set(pm.vertices, pm.indices) == _tri_set(np.asarray(mesh.positions, float), mesh.indices)
    n, t = pm.vertices[:, 5:8], pm.vertices[:, 8:12]
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-6)
    assert np.abs(np.einsum("ij,ij->i", n, t[:, :3])).max() < 1e-4  # the Duck's own (float32) normals


def test_inside_out_closed_meshes_are_warned_about():
    """A closed, consistently wound surface with a negative volume faces inward: the mesh step
    warns (not for a double-sided material, an open mesh or a non-manifold one)."""
    import trimesh

    from assetpipe.pipelines.mesh_process import inside_out

    s = trimesh.creation.icosphere(3)
    pos, tris = np.asarray(s.vertices), np.asarray(s.faces)
    flipped = tris[:, ::-1]
    assert not inside_out(pos, tris) and inside_out(pos, flipped)
    assert inside_out(pos + 1e6, flipped) and not inside_out(pos + 1e6, tris)  # far from the origin
    assert not inside_out(pos, flipped[:-1])  # open: its volume means nothing
    mixed = flipped.copy()
    mixed[0] = tris[0]
    assert not inside_out(pos, mixed)  # one triangle wound the other way: not consistent
    # UV seams split vertices at one position: still closed
    split = np.vstack([pos, pos[:10]])
    seam = flipped.copy()
    seam[seam < 10] += len(pos)
    assert inside_out(split, np.vstack([seam[:50], flipped[50:]]))

    mesh = MeshData(name="ball", positions=pos, indices=flipped.astype(np.uint32))
    warned = process_mesh(mesh, MeshOptions(optimize=False)).warnings
    assert any("inside out" in w for w in warned), warned
    assert not any("inside out" in w for w in process_mesh(mesh, MeshOptions(optimize=False),
                                                            double_sided=True).warnings)
    ok = MeshData(name="ball", positions=pos, indices=tris.astype(np.uint32))
    assert not any("inside out" in w for w in process_mesh(ok, MeshOptions(optimize=False)).warnings)


def test_optimize_order_plans_are_reused_with_the_same_output():
    """Two meshes with one index buffer (copies at other places): the vertex-cache and fetch
    optimisation is made once and gives each what it would alone."""
    from assetpipe.pipelines.mesh_process import optimize_order

    rng = np.random.default_rng(4)
    tris = rng.integers(0, 60, (150, 3)).astype(np.uint32)
    a = rng.normal(size=(60, 5)).astype(np.float32)
    b = a + 10.0
    plans: dict = {}
    for verts in (a, b):
        alone = optimize_order(verts, tris)
        shared = optimize_order(verts, tris, plans)
        assert np.array_equal(alone[0], shared[0]) and np.array_equal(alone[1], shared[1])
    assert len(plans) == 1
    optimize_order(a[:59], tris % 59, plans)  # another buffer: a plan of its own
    assert len(plans) == 2
