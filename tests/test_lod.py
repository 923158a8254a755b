"""LOD chains: counts down, measured error up, seams closed, borders locked, any frame."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from assetpipe.pipelines.lod import (
    DEFAULT_LOD_OPTIONS, LodOptions, build_lod_chain, reorder_for_lod_prefix)

FAST = LodOptions(error_samples=5000)


def _bumpy_sphere(sub: int = 5, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(subdivisions=sub)
    v = np.asarray(m.vertices, np.float64)
    rng = np.random.default_rng(seed)
    k = rng.normal(size=(6, 3)) * 4
    v = v * (1 + 0.05 * np.sin(v @ k.T).sum(axis=1))[:, None]
    return v, np.asarray(m.faces, np.uint32)


def _load_merged(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A corpus file as one mesh: positions f64, faces u32, uv f32|None, normals f32|None."""
    s = trimesh.load(path, process=False)
    if isinstance(s, trimesh.Trimesh):
        s = trimesh.Scene(s)
    P, F, U, N, off, has_uv, has_n = [], [], [], [], 0, True, True
    for node in s.graph.nodes_geometry:
        T, name = s.graph[node]
        g = s.geometry[name]
        if not isinstance(g, trimesh.Trimesh) or len(g.faces) == 0:
            continue
        v = np.asarray(g.vertices, np.float64) @ T[:3, :3].T + T[:3, 3]
        f = np.asarray(g.faces, np.int64)
        if np.linalg.det(T[:3, :3]) < 0:
            f = f[:, ::-1]
        uv = getattr(g.visual, "uv", None)
        if uv is None or len(uv) != len(v):
            has_uv, uv = False, np.zeros((len(v), 2))
        n = g._cache.cache.get("vertex_normals")
        if n is None or len(n) != len(v):
            has_n, n = False, np.zeros((len(v), 3))
        else:
            n = n @ np.linalg.inv(T[:3, :3])
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        P.append(v), F.append(f + off), U.append(uv), N.append(n)
        off += len(v)
    return (np.concatenate(P), np.concatenate(F).astype(np.uint32),
            np.concatenate(U).astype(np.float32) if has_uv else None,
            np.concatenate(N).astype(np.float32) if has_n else None)


def _check_chain(chain, n_vertices, m0):
    lv = chain.levels
    assert lv[0].triangles == m0 and lv[0].hausdorff == 0.0 and lv[0].switch_distance == 0.0
    for prev, cur in zip(lv, lv[1:]):
        assert cur.triangles < prev.triangles
        assert cur.triangles <= (1 - DEFAULT_LOD_OPTIONS.min_saving) * prev.triangles
        assert cur.indices.dtype == np.uint32 and cur.indices.shape == (cur.triangles, 3)
        assert cur.indices.size == 0 or cur.indices.max() < n_vertices
        assert cur.switch_distance >= prev.switch_distance
    for lvl in lv:
        for x in (lvl.hausdorff, lvl.rms, lvl.hausdorff_rel, lvl.rms_rel, lvl.switch_distance):
            assert math.isfinite(x) and x >= 0


def _assert_error_non_decreasing(chain):
    """Coarser levels are farther from level 0. The recorded values are bounds: only where
    both bounds converged (within 5% of the distance they evaluated) is their order the true
    order up to that 5%; an unconverged bound is checked to hold its lower value."""
    for prev, cur in zip(chain.levels, chain.levels[1:]):
        assert cur.hausdorff_rel >= cur.hausdorff_lower_rel, cur
        if prev.converged and cur.converged:
            assert cur.hausdorff_rel >= prev.hausdorff_lower_rel, (prev, cur)
        assert cur.rms_rel >= prev.rms_rel, (prev, cur)


def test_chain_counts_down_and_error_up():
    v, f = _bumpy_sphere()
    chain = build_lod_chain(v, f, options=FAST)
    assert len(chain.levels) == 5
    assert chain.levels[0].indices is not None
    np.testing.assert_array_equal(chain.levels[0].indices, f)
    _check_chain(chain, len(v), len(f))
    _assert_error_non_decreasing(chain)
    # 1/2, 1/4, 1/8, 1/16 of the input, within a few triangles
    for lvl, r in zip(chain.levels[1:], DEFAULT_LOD_OPTIONS.ratios[1:]):
        assert lvl.triangles == pytest.approx(r * len(f), rel=0.02)
    # switch distance: Hausdorff projects to one pixel at 1080 px, 60 degrees
    last = chain.levels[-1]
    assert last.switch_distance == pytest.approx(
        max(lv.hausdorff for lv in chain.levels) * 540 / math.tan(math.radians(30)))
    assert last.error_json()["hausdorffRel"] == last.hausdorff_rel


def test_input_not_modified_and_deterministic():
    v, f = _bumpy_sphere(4)
    v0, f0 = v.copy(), f.copy()
    a = build_lod_chain(v, f, options=FAST)
    b = build_lod_chain(v, f, options=FAST)
    np.testing.assert_array_equal(v, v0)
    np.testing.assert_array_equal(f, f0)
    for x, y in zip(a.levels, b.levels):
        np.testing.assert_array_equal(x.indices, y.indices)
        assert x.hausdorff == y.hausdorff and x.rms == y.rms


@pytest.mark.parametrize("simplifier", ["meshopt", "meshopt-attr", "fast-simplification"])
def test_simplifiers(simplifier):
    v, f = _bumpy_sphere(4)
    uv = (v[:, :2] * 0.5 + 0.5).astype(np.float32)
    chain = build_lod_chain(v, f, uv=uv, options=LodOptions(simplifier=simplifier, error_samples=3000))
    assert len(chain.levels) >= 4
    lv = chain.levels
    assert all(b.triangles < a.triangles for a, b in zip(lv, lv[1:]))
    assert all(math.isfinite(x.hausdorff) for x in lv)


def test_offset_and_scale_invariance():
    """Same relative error for the mesh offset by 1e3..1e7 and scaled by 1e-6..1e6.

    Combinations where offset / scale >= 1e7 are left out: there the *input* float64
    coordinates keep ~1e-9 of the mesh size or less (offset 1e7, scale 1e-6 quantises every
    vertex to 0.2% of the mesh), so it is a different mesh, and greedy simplification of a
    different mesh legitimately makes different choices. At exactly 1e7 (a 1.9e-9 grid, 1/30
    of the float32 step the simplifier works in) the levels with moved vertices
    (``move_vertices``), each simplified from the one above, measured 0.949-1.034x the
    untranslated chain's errors (LOD step 19); with vertices in place they were equal.
    """
    v, f = _bumpy_sphere(4)
    v = v + np.random.default_rng(5).normal(size=v.shape) * 2e-3  # no exact ties
    base = build_lod_chain(v, f, options=FAST)
    cases = [(o, s) for o in (0.0, 1e3, 1e5, 1e7) for s in (1e-6, 1e-3, 1.0, 1e3, 1e6)
             if o / s < 1e7]
    assert len(cases) >= 14
    for offset, scale in cases:
        chain = build_lod_chain(v * scale + offset, f, options=FAST)
        assert [x.triangles for x in chain.levels] == [x.triangles for x in base.levels]
        for a, b in zip(base.levels[1:], chain.levels[1:]):
            assert b.hausdorff_rel == pytest.approx(a.hausdorff_rel, rel=0.05), (offset, scale)
            assert b.rms_rel == pytest.approx(a.rms_rel, rel=0.05), (offset, scale)
            assert b.hausdorff == pytest.approx(a.hausdorff * scale, rel=0.05)
            assert b.switch_distance == pytest.approx(a.switch_distance * scale, rel=0.05)
            assert b.hausdorff_rel > 0


def _border_edges_by_position(pos: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(B, 2) sorted position-id pairs of the edges used by exactly one triangle."""
    _, pid = np.unique(pos, axis=0, return_inverse=True)
    t = pid.reshape(-1)[tri.astype(np.int64)]
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    e = e[e[:, 0] != e[:, 1]]
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq[counts == 1]


def _border_length(pos, tri):
    _, first, pid = np.unique(pos, axis=0, return_index=True, return_inverse=True)
    e = _border_edges_by_position(pos, tri)
    p = pos[first]
    return float(np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1).sum())


def test_uv_seams_stay_closed_duck(corpus):
    v, f, uv, n = _load_merged(corpus / "models" / "Duck" / "glTF" / "Duck.gltf")
    assert uv is not None
    b0 = _border_edges_by_position(v, f)
    border_vertices = set(b0.ravel().tolist())
    chain = build_lod_chain(v, f, uv=uv, normals=n, options=FAST)
    assert len(chain.levels) == 5
    _assert_error_non_decreasing(chain)
    for k, lvl in enumerate(chain.levels[1:], start=1):
        if any(x.sloppy for x in chain.levels[: k + 1]):  # sloppy clusters: no seam guarantee
            continue
        b = _border_edges_by_position(v, lvl.indices)
        # no new holes: every border edge by position runs between original border vertices
        assert set(b.ravel().tolist()) <= border_vertices, lvl.level


def test_locked_borders_bunny(corpus):
    v, f, _, _ = _load_merged(corpus / "models" / "stanford-bunny" / "stanford-bunny.obj")
    b0 = _border_edges_by_position(v, f)
    assert len(b0) > 0  # the bunny has open borders
    length0 = _border_length(v, f)
    chain = build_lod_chain(v, f, options=LodOptions(lock_border=True, error_samples=5000))
    assert len(chain.levels) >= 4
    _assert_error_non_decreasing(chain)
    for lvl in chain.levels[1:]:
        b = _border_edges_by_position(v, lvl.indices)
        assert set(b.ravel().tolist()) <= set(b0.ravel().tolist())
        assert _border_length(v, lvl.indices) == pytest.approx(length0, rel=1e-9)
        assert not lvl.sloppy


def test_reorder_for_lod_prefix():
    v, f = _bumpy_sphere(4)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(v))  # scatter the vertices, add 5 unreferenced ones
    inv = np.argsort(perm)
    v2 = np.concatenate([v[perm], np.zeros((5, 3))])
    f2 = inv[f].astype(np.uint32)
    chain = build_lod_chain(v2, f2, options=FAST)
    levels = [lvl.indices for lvl in chain.levels]
    r = reorder_for_lod_prefix(levels, len(v2))
    assert sorted(r.order.tolist()) == list(range(len(v2)))
    np.testing.assert_array_equal(r.order[r.remap], np.arange(len(v2)))
    counts = r.vertex_counts
    assert counts[0] == len(v) and all(a >= b for a, b in zip(counts, counts[1:]))
    new_pos = v2[r.order]
    for k, (old, new) in enumerate(zip(levels, r.indices)):
        assert new.dtype == np.uint32
        assert new.max() < counts[k]
        np.testing.assert_array_equal(new_pos[new], v2[old])  # same triangles, same corners
        assert len(np.unique(new)) == counts[k] if k == len(levels) - 1 else True
    # the unreferenced vertices come last
    assert set(r.order[counts[0]:].tolist()) == set(range(len(v), len(v) + 5))


def _sliver_mesh():
    v, f = _bumpy_sphere(3)
    # add slivers (near-collinear), duplicate vertices, a non-manifold fin, an open flap
    n = len(v)
    extra = np.array([[2, 0, 0], [3, 0, 0], [4, 1e-9, 0], [2, 0, 0], [0, 0, 2], [0, 1, 2], [1, 0, 2]],
                     np.float64)
    v2 = np.concatenate([v, extra])
    e = f[0]
    more = np.array([[n, n + 1, n + 2], [n + 3, n + 1, n + 2], [e[0], e[1], n + 4],
                     [e[1], e[0], n + 5], [e[0], e[1], n + 6], [n + 4, n + 5, n + 6]], np.uint32)
    return v2, np.concatenate([f, more, f[:5]])  # f[:5]: duplicate faces


@pytest.mark.parametrize("simplifier", ["meshopt", "meshopt-attr", "fast-simplification"])
def test_nasty_inputs_do_not_crash(simplifier):
    opts = LodOptions(simplifier=simplifier, error_samples=2000)
    v, f = _sliver_mesh()
    chain = build_lod_chain(v, f, options=opts)
    _check_chain(chain, len(v), len(f))
    # a single triangle, an empty mesh, all-degenerate, a single point, NaN-free tiny mesh
    tri = np.array([[0, 1, 2]], np.uint32)
    p3 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    chain = build_lod_chain(p3, tri, options=opts)
    assert len(chain.levels) == 1 and chain.levels[0].triangles == 1
    chain = build_lod_chain(p3, np.zeros((0, 3), np.uint32), options=opts)
    assert len(chain.levels) == 1 and chain.levels[0].triangles == 0
    chain = build_lod_chain(np.zeros((0, 3)), np.zeros((0, 3), np.uint32), options=opts)
    assert len(chain.levels) == 1
    same = np.zeros((3, 3))
    chain = build_lod_chain(same, np.repeat(tri, 100, axis=0), options=opts)
    assert all(math.isfinite(x.hausdorff) for x in chain.levels)


def test_target_errors_mode():
    v, f = _bumpy_sphere(5)
    chain = build_lod_chain(v, f, options=LodOptions(ratios=(1.0,), target_errors=(0.0, 0.002, 0.01),
                                                     error_samples=3000))
    assert len(chain.levels) == 3
    assert chain.levels[1].triangles > chain.levels[2].triangles


def test_options_validated():
    from assetpipe.core.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown simplifier"):
        LodOptions(simplifier="nope")
    with pytest.raises(ConfigError, match="first LOD step must be level 0"):
        LodOptions(ratios=(0.5, 0.25))


def _ancestry(chain, k):
    """Level k and the levels it was simplified from (through ``from_level``)."""
    out = [chain.levels[k]]
    while k > 0:
        k = chain.levels[k].from_level
        out.append(chain.levels[k])
    return out


@pytest.mark.corpus
def test_corpus_chains(corpus):
    """Every corpus file: chain invariants, non-decreasing error, closed seams (non-sloppy)."""
    files = sorted([*corpus.glob("models/*/*.obj"), *corpus.glob("models/*/*.glb"),
                    *corpus.glob("models/*/glTF/*.gltf")])
    assert files
    for path in files:
        v, f, uv, n = _load_merged(path)
        chain = build_lod_chain(v, f, uv=uv, normals=n, options=LodOptions(error_samples=20000))
        _check_chain(chain, len(v), len(f))
        _assert_error_non_decreasing(chain)
        b0 = set(_border_edges_by_position(v, f).ravel().tolist())
        for k, lvl in enumerate(chain.levels[1:], start=1):
            # a level made by the sloppy fallback, and every level simplified from it, may
            # have cracks (clustering ignores seams): only sloppy-free descent is checked
            if not any(x.sloppy for x in _ancestry(chain, k)):
                assert set(_border_edges_by_position(v, lvl.indices).ravel().tolist()) <= b0, path


def test_cesium_man_with_normals_reaches_targets(corpus):
    """CesiumMan with UVs and normals used to stall at ~855 triangles for 1/8 and 1/16
    (targets 584, 292; measured Hausdorff 7.2% and, through the sloppy fallback, 28.6%):
    welding left unreferenced twins that meshoptimizer locked. Now every level is reached by
    the regular simplifier with small error."""
    v, f, uv, n = _load_merged(corpus / "models" / "CesiumMan" / "glTF" / "CesiumMan.gltf")
    assert uv is not None and n is not None
    chain = build_lod_chain(v, f, uv=uv, normals=n, options=FAST)
    assert len(chain.levels) == 5
    _check_chain(chain, len(v), len(f))
    for lvl, r in zip(chain.levels[1:], DEFAULT_LOD_OPTIONS.ratios[1:]):
        assert lvl.triangles == pytest.approx(r * len(f), rel=0.02), lvl.level
        assert not lvl.sloppy
    assert chain.levels[3].hausdorff_rel < 0.015 and chain.levels[4].hausdorff_rel < 0.03


def test_stalled_step_falls_back_to_pruning_spider(corpus):
    """The merged spider (19 small parts) stalled at 105 triangles for 1/16 (target 85,
    Hausdorff 25% of the diagonal): a 1.24x miss was inside the old 1.5x slack. Now the
    alternatives run whenever the target is missed by more than 10%, and the measured best
    (component pruning: seams stay closed, not sloppy) is kept."""
    v, f, uv, n = _load_merged(corpus / "models" / "spider" / "spider.obj")
    chain = build_lod_chain(v, f, uv=uv, normals=n, options=LodOptions(error_samples=20000,
                                                                       max_error=None))
    _check_chain(chain, len(v), len(f))
    last = chain.levels[-1]
    assert len(chain.levels) == 5
    assert last.triangles <= 1.1 * round(len(f) / 16)
    assert last.hausdorff_rel < 0.2 and not last.sloppy
    # the default error budget (10% of the diagonal) does not emit a level above it
    budgeted = build_lod_chain(v, f, uv=uv, normals=n, options=LodOptions(error_samples=20000))
    assert all(lv.hausdorff_rel <= DEFAULT_LOD_OPTIONS.max_error for lv in budgeted.levels)
    assert len(budgeted.levels) == 5 or last.hausdorff_rel > DEFAULT_LOD_OPTIONS.max_error
    # without measuring, the choice falls back to the simplifier's estimate: still reached
    quick = build_lod_chain(v, f, uv=uv, normals=n, options=LodOptions(measure=False))
    assert quick.levels[-1].triangles <= 1.1 * round(len(f) / 16)


def _wavy_uv_sphere():
    """The bumpy sphere with UVs that wave across it (continuous, no seams): weighing them
    costs geometric error, and the worst places of a level are few."""
    v, f = _bumpy_sphere(4)
    uv = np.stack([np.sin(9 * v[:, 0]) + v[:, 2], np.cos(7 * v[:, 1]) * v[:, 2]], 1)
    return v, f, uv.astype(np.float32)


def test_geometry_candidate_and_locked_refinement_lower_the_bound():
    """Each rule is kept only where the estimate says it is closer to level 0; on this mesh
    both lower the recorded bound at some level and raise it at none (same triangle counts)."""
    v, f, uv = _wavy_uv_sphere()
    # the two rules refine levels over level 0's vertices; moved levels (move_vertices) win
    # every step of this smooth sphere and would hide them
    opts = dict(error_samples=3000, move_vertices=False)

    def bounds(**kw):
        chain = build_lod_chain(v, f, uv=uv, options=LodOptions(**opts, **kw))
        _check_chain(chain, len(v), len(f))
        return [lv.triangles for lv in chain.levels], [lv.hausdorff_rel for lv in chain.levels]

    # both rules are off by default (docs/BUILD.md): on here
    counts, both = bounds(geometry_candidate=True, lock_fraction=0.7)
    for off in ({"geometry_candidate": False, "lock_fraction": 0.7},
                {"geometry_candidate": True, "lock_fraction": 0.0}):
        c, without = bounds(**off)
        assert c == counts
        assert all(a <= b for a, b in zip(both, without)), (off, both, without)
        assert any(a < b for a, b in zip(both, without)), (off, both, without)


def test_lock_fraction_validated():
    from assetpipe.core.errors import ConfigError

    with pytest.raises(ConfigError, match="lock_fraction must be in"):
        LodOptions(lock_fraction=1.5)
    LodOptions(lock_fraction=0.0)  # off is allowed


def test_estimator_lowest_of_keeps_the_lowest_candidate_and_its_value():
    """Asked only for the lowest estimate among some candidates, the estimator stops each one's
    halves once above the lowest found: the same candidate comes out lowest, with the same
    value; the others get a value above it and at most their full value."""
    from assetpipe.pipelines import simplify as simp
    from assetpipe.pipelines.lod import _Estimator

    v, f = _bumpy_sphere(4, seed=3)
    local = (v - v.mean(0)) / np.linalg.norm(np.ptp(v, 0))
    pos32 = np.ascontiguousarray(local, np.float32)
    cands = []
    for target in (f.shape[0] // 2, f.shape[0] // 3, f.shape[0] // 5, f.shape[0] // 9):
        tri, err = simp.simplify(pos32, f, target)
        cands.append((tri, err, False, 0, None))
    est = _Estimator(local, f.astype(np.int64), 2000, 11)
    full = est(cands)
    assert len(set(full)) == len(full)  # distinct: the test can tell them apart
    # the level-0 BVH of a reference side handed in (the recorded bound's) gives the same
    # estimates; it is built on the first call, not before
    from assetpipe.pipelines.surface_error import _Side
    side = _Side(local, f.astype(np.int64))
    shared = _Estimator(local, f.astype(np.int64), 2000, 11, side=side)
    assert side._engine is None
    assert shared(cands) == full
    assert side._engine is not None
    # the forward halves' BVHs are kept by candidate array (for the recorded bound) until
    # keep() names the chosen ones; asked again, a candidate reuses its BVH (same estimate)
    assert all(shared.engine_for(c[0]) is not None for c in cands)
    assert shared.engine_for(cands[0][0].copy()) is None  # by array, not by content
    again = shared(cands)
    assert again == full
    shared.keep([cands[1][0]])
    assert shared.engine_for(cands[1][0]) is not None and shared.engine_for(cands[0][0]) is None
    for lowest_of in ([0, 1, 2, 3], [1, 2, 3], [2, 3], [3, 0]):
        part = est(cands, lowest_of)
        i = min(lowest_of, key=lambda k: full[k])
        assert min(lowest_of, key=lambda k: part[k]) == i and part[i] == full[i]
        # the others: a lower value of their own, above the lowest (their evaluation stopped
        # there, never at it: a stop compared before the square root once let a loser tie)
        assert all(part[i] < part[k] <= full[k] for k in lowest_of if k != i)
        assert all(math.isnan(part[k]) for k in range(len(cands)) if k not in lowest_of)
    # candidates worse than the lowest stop early: some get less than their full value
    part = est(cands, [0, 1, 2, 3])
    assert sum(p < q for p, q in zip(part, full)) >= 1


def test_uv_sphere_with_pole_cells_builds_with_finite_bounds():
    """A UV sphere whose pole rows collapse to one point (and whose seam vertices differ by
    sin(2 pi) = -2.4e-16): a level's cell there had two corners 1e-17 apart, and the covering
    radius divided by an area that rounds to 0 (numba raises: the chain stopped). Built in
    place and with moved vertices, every level gets a finite bound."""
    pos, tri = _uv_sphere(12, 24, 1.0, 0.0)
    for move in (False, True):
        chain = build_lod_chain(pos, tri.astype(np.uint32), options=LodOptions(move_vertices=move))
        assert len(chain.levels) >= 3
        assert all(np.isfinite(lv.hausdorff) and lv.hausdorff >= 0 for lv in chain.levels)


def _uv_sphere(nu, nv, scale, offset):
    u, v = np.meshgrid(np.linspace(0.0, np.pi, nu + 1), np.linspace(0.0, 2.0 * np.pi, nv + 1), indexing="ij")
    pos = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1).reshape(-1, 3) * scale + offset
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = (i * (nv + 1) + j).reshape(-1)
    return pos, np.concatenate([np.stack([a, a + nv + 1, a + 1], 1), np.stack([a + 1, a + nv + 1, a + nv + 2], 1)])


def _hostile_mesh(kind, rng):
    """A mesh of one hostile kind, at a random scale (1e-6..1e6) and offset (up to 1e7)."""
    scale = 10.0 ** rng.uniform(-6, 6)
    offset = rng.normal(size=3) * 10.0 ** rng.uniform(-3, 7)
    if kind == "pole sphere":  # collapsed poles, a seam at sin(2 pi)
        return _uv_sphere(int(rng.integers(3, 30)), int(rng.integers(3, 40)), scale, offset)
    if kind == "soup":
        n = int(rng.integers(3, 300))
        return rng.normal(size=(n, 3)) * scale + offset, rng.integers(0, n, (int(rng.integers(1, 600)), 3))
    if kind == "slivers":  # nearly collinear points, 1e-16..1e-6 off the line
        n = int(rng.integers(3, 200))
        t = rng.random(n)
        pos = np.stack([t, 2 * t, 3 * t], 1) * scale + offset
        pos += rng.normal(size=(n, 3)) * scale * 10.0 ** rng.uniform(-16, -6)
        return pos, rng.integers(0, n, (int(rng.integers(1, 400)), 3))
    if kind == "sheets":  # a grid twice at one place and once 1e-12 above, reversed
        k = int(rng.integers(2, 25))
        x, y = np.meshgrid(np.arange(k), np.arange(k))
        p = np.stack([x.ravel(), y.ravel(), np.zeros(k * k)], 1).astype(float)
        q = (np.arange(k - 1)[:, None] * k + np.arange(k - 1)[None]).ravel()
        t = np.concatenate([np.stack([q, q + 1, q + k], 1), np.stack([q + 1, q + k + 1, q + k], 1)])
        return (np.concatenate([p, p, p + [0, 0, 1e-12]]) * scale + offset,
                np.concatenate([t, t + k * k, (t + 2 * k * k)[:, ::-1]]))
    if kind == "jittered sphere":  # poles and seam apart by 1e-17..1e-10 of the size
        pos, tri = _uv_sphere(int(rng.integers(3, 20)), int(rng.integers(3, 20)), scale, offset)
        return pos + rng.normal(size=pos.shape) * scale * 10.0 ** rng.uniform(-17, -10), tri
    n = int(rng.integers(3, 6))  # "tiny": one to three triangles
    return rng.normal(size=(n, 3)) * scale + offset, rng.integers(0, n, (int(rng.integers(1, 4)), 3))


@pytest.mark.parametrize("kind", ["pole sphere", "soup", "slivers", "sheets", "jittered sphere", "tiny"])
def test_hostile_geometry_builds_chains_with_bounds(kind):
    """Two meshes of each kind, with and without UVs, in place and with moved vertices: a
    chain comes out, every level's recorded bound is a number >= 0. (Looking for more cases
    like the pole cell's division by zero, 180 random meshes of these kinds ran clean.)"""
    rng = np.random.default_rng(sum(map(ord, kind)))
    for _ in range(2):
        pos, tri = _hostile_mesh(kind, rng)
        uv = rng.random((pos.shape[0], 2)).astype(np.float32) if rng.random() < 0.5 else None
        for move in (False, True):
            chain = build_lod_chain(pos, tri.astype(np.uint32), uv=uv, options=LodOptions(move_vertices=move))
            assert chain.levels[0].triangles == tri.shape[0]
            assert all(lv.hausdorff >= 0 and np.isfinite(lv.hausdorff_rel) for lv in chain.levels[1:])


def _subdivided(mesh, times: int):
    for _ in range(times):
        mesh = mesh.subdivide()
    return mesh


@pytest.mark.parametrize("name, mesh, move", [
    # flat faces: every level lies exactly on level 0 (meshoptimizer leaves zero-area triangles
    # and T-junctions there); before LOD step 22 one level ran out of work at 1.9e-7, 3.1 s
    ("subdivided box", _subdivided(trimesh.creation.box((1, 2, 3)), 4), False),
    # a cylinder's moved level: its side's slivers reach both rims; before LOD step 22 level 2
    # ran out of work at 0.00079 of the diagonal (3.3 s); converged, 0.00032
    ("cylinder", trimesh.creation.cylinder(0.5, 3, sections=256), True),
    ("two boxes", _subdivided(trimesh.util.concatenate([
        trimesh.creation.box((1, 1, 1)), trimesh.creation.box((0.5, 0.5, 2)).apply_translation((0.7, 0, 0))]), 3), False),
])
def test_cad_shapes_get_converged_bounds(name, mesh, move):
    """CAD's flat faces and creases: every level's bound converges (within the tolerance of a
    distance evaluated, not stopped by the work budget)."""
    chain = build_lod_chain(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.uint32),
                            normals=np.asarray(mesh.vertex_normals, np.float32),
                            options=LodOptions(move_vertices=move))
    assert len(chain.levels) >= 4
    assert [lv.converged for lv in chain.levels[1:]] == [True] * (len(chain.levels) - 1), name
    if not move:  # levels in place on flat faces: the surface is unchanged
        assert max(lv.hausdorff_rel for lv in chain.levels[1:]) <= 2 * 2.0 ** -23


def test_a_moved_levels_unmoved_rows_are_level_0s_bit_for_bit():
    """meshoptimizer's simplifyWithUpdate moves only the vertices collapses end on; the rows it
    leaves are level 0's positions exactly (not their float32 roundings in the chain's frame),
    so the output writes them as LOD0 writes them and the bound shares them. A bumpy open
    sheet's moved levels keep its border vertices (open borders stay put)."""
    n = 40
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    z = 0.05 * np.sin(7 * x) * np.cos(5 * y)
    pos = np.stack([x, y, z], -1).reshape(-1, 3) * 1.7 + [12.5, -3.25, 0.1]
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    tri = np.concatenate([np.stack([a, a + n + 1, a + n + 2], 1), np.stack([a, a + n + 2, a + 1], 1)])
    chain = build_lod_chain(pos, tri.astype(np.uint32), options=LodOptions(move_vertices=True))
    moved = [lv for lv in chain.levels[1:] if lv.positions is not None]
    assert moved
    for lv in moved:
        used = np.unique(lv.indices.reshape(-1))
        same = np.all(lv.positions[used] == pos[used], axis=1)
        assert 0 < same.sum() < used.size
        # the border vertices (locked: never moved) among them, every one
        border = used[(x.ravel()[used] % 1 == 0) | (y.ravel()[used] % 1 == 0)]
        assert border.size and np.array_equal(lv.positions[border], pos[border])
    # the rows it does not use are level 0's too
    unused = np.setdiff1d(np.arange(pos.shape[0]), np.unique(moved[0].indices.reshape(-1)))
    assert np.array_equal(moved[0].positions[unused], pos[unused])
