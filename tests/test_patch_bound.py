"""The height-field ("patch") bound (pipelines/patch_bound.py) against dense brute force: every
value it gives must be at least the largest exact distance found on the cell, and it must say
it cannot bound a cell over a hole, a fold or a non-manifold edge."""

import numpy as np
import pytest

from assetpipe.pipelines.closest_point import ClosestTriangles
from assetpipe.pipelines.patch_bound import (
    PATCH_MAX, WHY_BORDER, WHY_BOUNDED, WHY_FOLDED, WHY_NON_MANIFOLD, WHY_TOO_MANY, patch_bound,
    patch_bound_seeded)
from assetpipe.pipelines.surface_error import edge_neighbours, points_to_mesh_distance

# every test runs with the patch gathered from the BVH alone (``patch_bound``) and grown first
# from seed triangles across shared edges, as the bound calls it (``patch_bound_seeded``: the
# target triangles nearest the cell's corners, as its first round knows them)
_GATHER = ["bvh"]


@pytest.fixture(autouse=True, params=["bvh", "grown"])
def _gather(request):
    _GATHER[0] = request.param
    yield
    _GATHER[0] = "bvh"


def _grid(n, f, lo=0.0, hi=1.0):
    """A height field z = f(x, y) over [lo, hi]^2: (n*n, 3) positions, (2(n-1)^2, 3) triangles,
    counter-clockwise seen from +z."""
    x, y = np.meshgrid(np.linspace(lo, hi, n), np.linspace(lo, hi, n))
    pos = np.stack([x.ravel(), y.ravel(), f(x, y).ravel()], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return pos, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _bound(pos, tri, cells, rho):
    tree = ClosestTriangles.build(pos, tri)
    _, inv = np.unique(pos, axis=0, return_inverse=True)
    wtri = inv.reshape(-1)[tri]
    cells = np.ascontiguousarray(cells, dtype=np.float64)
    wtri = np.ascontiguousarray(wtri, dtype=np.int64)
    if _GATHER[0] == "bvh":
        return patch_bound(cells, np.full(cells.shape[0], rho), *tree.nodes, tree.a, tree.b, tree.c, wtri)
    _, f = tree.query(cells.reshape(-1, 3))
    f = f.reshape(-1, 3)
    seeds = np.ascontiguousarray(np.stack([f[:, 0], f[:, 0], f[:, 1], f[:, 2]], 1))
    return patch_bound_seeded(cells, np.full(cells.shape[0], rho), *tree.nodes, tree.a, tree.b, tree.c,
                              wtri, edge_neighbours(wtri), seeds)


def _dense_max(cell, pos, tri, rng, n=3000):
    """Largest exact distance over n random points of the cell and its corners (a lower
    value of the true maximum)."""
    u = rng.random((n, 2))
    flip = u.sum(1) > 1
    u[flip] = 1 - u[flip]
    p = cell[0] + u[:, :1] * (cell[1] - cell[0]) + u[:, 1:] * (cell[2] - cell[0])
    return points_to_mesh_distance(np.concatenate([p, cell]), pos, tri).max()


def _bump(x, y):
    return 0.05 * np.sin(7 * x) * np.cos(5 * y)


@pytest.mark.parametrize("lift", [0.0, 0.01, -0.02])
def test_bumpy_surface_bounded_tightly_and_never_below_the_truth(lift):
    rng = np.random.default_rng(1)
    pos, tri = _grid(17, _bump)
    # a coarse level of the same surface (corners on it), inside the fine one's border: a cell
    # reaching over the border is not covered (the border's projection dips into it)
    cpos, ctri = _grid(6, _bump, 0.1, 0.9)
    cells = cpos[ctri] + np.array([0.0, 0.0, lift])
    val, why = _bound(pos, tri, cells, 0.05)
    ok = np.flatnonzero(why == WHY_BOUNDED)
    assert ok.size == cells.shape[0]
    ratio = []
    for i in ok:
        dense = _dense_max(cells[i], pos, tri, rng)
        assert val[i] >= dense, (i, val[i], dense)
        ratio.append(val[i] / dense)
    # tight: vertical distance over a gently sloped surface, at most its 1/cos (slope of the
    # bumps up to 0.35: 1/cos <= 1.06), measured 1.00-1.03 here
    assert np.median(ratio) < 1.03 and max(ratio) < 1.07


def test_sphere_level_bounded_from_both_sides():
    import trimesh

    rng = np.random.default_rng(2)
    fine, coarse = trimesh.creation.icosphere(4), trimesh.creation.icosphere(2)
    pos, tri = np.asarray(fine.vertices, float), np.asarray(fine.faces)
    cells = np.asarray(coarse.vertices)[coarse.faces]
    val, why = _bound(pos, tri, cells, 0.05)
    assert (why == WHY_BOUNDED).all()
    for i in rng.choice(cells.shape[0], 40, replace=False):
        assert val[i] >= _dense_max(cells[i], pos, tri, rng)
    # and the other way: fine cells against the coarse level (cells on a chord's plane side)
    val2, why2 = _bound(np.asarray(coarse.vertices, float), np.asarray(coarse.faces), pos[tri], 0.05)
    assert (why2 == WHY_BOUNDED).mean() > 0.9
    for i in rng.choice(np.flatnonzero(why2 == WHY_BOUNDED), 40, replace=False):
        assert val2[i] >= _dense_max(pos[tri][i], np.asarray(coarse.vertices, float),
                                     np.asarray(coarse.faces), rng)


def test_hole_under_the_cell_is_not_bounded():
    pos, tri = _grid(9, lambda x, y: 0 * x)
    cell = np.array([[[0.2, 0.2, 0.01], [0.8, 0.2, 0.01], [0.5, 0.8, 0.01]]])
    # the triangle under the middle of the cell removed: a hole the vertical lines fall through
    centre = pos[tri].mean(axis=1)
    hole = np.argmin(np.linalg.norm(centre[:, :2] - [0.5, 0.4], axis=1))
    val, why = _bound(pos, np.delete(tri, hole, axis=0), cell, 0.1)
    assert why[0] == WHY_BORDER and val[0] == np.inf
    # without the hole: bounded, at the cell's height
    val, why = _bound(pos, tri, cell, 0.1)
    assert why[0] == WHY_BOUNDED and 0.01 <= val[0] < 0.01 * (1 + 1e-6)


def test_fold_under_the_cell_is_not_bounded():
    # a sheet folded back under itself along x = 0.5 (a Z shape seen from the side): the
    # upper part's vertical lines meet the folded part first
    pos, tri = _grid(9, lambda x, y: 0 * x)
    over = pos.copy()
    over[:, 0] = 1.0 - over[:, 0] * 0.5          # x in [0.5, 1], mirrored
    over[:, 2] = 0.05 - pos[:, 0] * 0.05          # rising back to z = 0.05 at x = 0.5
    n = pos.shape[0]
    # glue the two along x = 0.5... approximately: the folded copy shares no vertex, so its
    # edge over the cell is a border; the fold itself, with shared vertices, is a fold
    allpos = np.concatenate([pos, over])
    alltri = np.concatenate([tri, tri[:, ::-1] + n])  # the folded copy faces down
    cell = np.array([[[0.55, 0.2, 0.1], [0.95, 0.2, 0.1], [0.75, 0.8, 0.1]]])
    val, why = _bound(allpos, alltri, cell, 0.2)
    # whatever the verdict, a value given is never below the truth
    rng = np.random.default_rng(4)
    if why[0] == WHY_BOUNDED:
        assert val[0] >= _dense_max(cell[0], allpos, alltri, rng)
    # a true fold with shared vertices: an accordion z = |saw(x)| whose middle vertices are
    # pulled past their neighbours in x, so two triangles of one edge lie on one side of it
    pos2, tri2 = _grid(9, lambda x, y: 0 * x)
    col = np.isclose(pos2[:, 0], 0.5)
    pos2[col, 0] = 0.7  # the column x = 0.5 moved past x = 0.625: its triangles fold over
    pos2[col, 2] = 0.02
    cell2 = np.array([[[0.3, 0.1, 0.05], [0.9, 0.1, 0.05], [0.6, 0.9, 0.05]]])
    val2, why2 = _bound(pos2, tri2, cell2, 0.2)
    assert why2[0] in (WHY_FOLDED, WHY_BORDER) and val2[0] == np.inf


def test_fin_on_an_edge_under_the_cell_is_not_bounded():
    pos, tri = _grid(9, lambda x, y: 0 * x)
    # a fin on the edge of triangle 20, tilted so it faces up like the sheet
    t = tri[20]
    tip = pos[t[:2]].mean(axis=0) + np.array([0.05, 0.05, 0.03])
    pos2 = np.concatenate([pos, tip[None]])
    tri2 = np.concatenate([tri, [[t[0], t[1], pos.shape[0]]]])
    c = pos[t].mean(axis=0)
    cell = np.array([[c + [-0.2, -0.2, 0.05], c + [0.2, -0.2, 0.05], c + [0.0, 0.25, 0.05]]])
    val, why = _bound(pos2, tri2, cell, 0.2)
    if _GATHER[0] == "grown":
        # the patch grown across shared edges never crosses the edge three triangles share: the
        # sheet without the fin covers the cell, and a bound over part of the target bounds the
        # distance to all of it (at least the truth, which the fin can only lower)
        assert why[0] == WHY_BOUNDED
        assert val[0] >= _dense_max(cell[0], pos2, tri2, np.random.default_rng(0)) - 1e-12
        assert val[0] <= 0.05 + 1e-9
        return
    # the edge has three triangles, and the fin's free edges are borders over the cell
    assert why[0] in (WHY_NON_MANIFOLD, WHY_BORDER) and val[0] == np.inf


def test_too_many_triangles_near_the_cell():
    pos, tri = _grid(41, lambda x, y: 0 * x)  # 3200 triangles under one big cell
    assert tri.shape[0] > PATCH_MAX
    cell = np.array([[[0.0, 0.0, 0.01], [1.0, 0.0, 0.01], [0.0, 1.0, 0.01]]])
    val, why = _bound(pos, tri, cell, 0.1)
    assert why[0] == WHY_TOO_MANY and val[0] == np.inf


def test_random_noisy_surfaces_never_below_dense_samples():
    # rough surfaces with slivers and steep parts: whatever is bounded holds
    rng = np.random.default_rng(7)
    for trial in range(4):
        pos, tri = _grid(21, lambda x, y: 0.03 * np.sin(11 * x + trial) * np.cos(13 * y))
        pos = pos + rng.normal(scale=0.004, size=pos.shape) * [1, 1, 3]
        cpos, ctri = _grid(6, lambda x, y: 0 * x, 0.05, 0.95)
        cells = cpos[ctri] + rng.normal(scale=0.01, size=(ctri.shape[0], 3, 3))
        val, why = _bound(pos, tri, cells, 0.1)
        for i in np.flatnonzero(why == WHY_BOUNDED):
            assert val[i] >= _dense_max(cells[i], pos, tri, rng, 1500), (trial, i)


def test_side_value_shortcuts_agree_with_the_full_tests():
    """What patch_bound decides from T's side values alone (corners of F in 2D, T's edges CCW)
    is what the full tests say: all of F outside one edge (by the margin): separated; one
    corner inside all three by more than the margin: not separated; every corner inside: the
    clipped polygon is F itself, bit for bit. Random triangles around T, some near its edges
    and corners, at two margins."""
    from assetpipe.pipelines.patch_bound import _clip, _separated

    rng = np.random.default_rng(7)
    tx, ty = np.array([0.0, 1.0, 0.3]), np.array([0.0, 0.0, 0.8])
    counts = {"out": 0, "in": 0, "all in": 0}
    for margin in (1e-12, 1e-3):
        for _ in range(20000):
            if rng.random() < 0.25:  # corners inside T (barycentric), some on its edges
                w = rng.dirichlet([1.0, 1.0, 1.0], 3) * (rng.random((3, 1)) < 0.8)
                w[:, 0] = 1.0 - w[:, 1:].sum(1)
                fx, fy = w @ tx, w @ ty
            else:
                fx = rng.choice([0.0, 1.0, 0.3], 3) + rng.normal(0.0, rng.choice([1e-12, 1e-3, 0.3]), 3)
                fy = rng.choice([0.0, 0.0, 0.8], 3) + rng.normal(0.0, rng.choice([1e-12, 1e-3, 0.3]), 3)
            if (fx[1] - fx[0]) * (fy[2] - fy[0]) - (fy[1] - fy[0]) * (fx[2] - fx[0]) < 0:
                fx, fy = fx[::-1].copy(), fy[::-1].copy()
            ex, ey = np.roll(tx, -1) - tx, np.roll(ty, -1) - ty
            lim = margin * np.hypot(ex, ey)
            val = ex[:, None] * (fy[None] - ty[:, None]) - ey[:, None] * (fx[None] - tx[:, None])  # (edge, corner)
            sep = _separated(fx, fy, 3, tx, ty, -margin)
            if (val <= lim[:, None]).all(axis=1).any():
                counts["out"] += 1
                assert sep
            if (val > lim[:, None]).all(axis=0).any():
                counts["in"] += 1
                assert not sep
            if (val >= 0).all():
                counts["all in"] += 1
                ox, oy, bx, by = (np.empty(12) for _ in range(4))
                assert _clip(fx, fy, tx, ty, ox, oy, bx, by) == 3
                assert (ox[:3] == fx).all() and (oy[:3] == fy).all()
    assert min(counts.values()) > 500, counts  # each case was met


def test_a_second_sheet_with_a_border_over_the_cell_is_left_out():
    """A washer lying on a plate (CAD parts touch): its open rim reaches into the cell, so the
    washer's component is left out and the plate alone proves the cover. Without the plate
    under the rim (the plate holed there) the cell is still given up."""
    rng = np.random.default_rng(5)
    pos, tri = _grid(9, lambda x, y: 0 * x)
    # the washer: a small square sheet 0.004 above the plate, facing up, sharing no vertex
    wpos, wtri_ = _grid(3, lambda x, y: 0 * x + 0.004, 0.4, 0.6)
    allpos = np.concatenate([pos, wpos])
    alltri = np.concatenate([tri, wtri_ + pos.shape[0]])
    cell = np.array([[[0.2, 0.2, 0.01], [0.8, 0.2, 0.01], [0.5, 0.8, 0.01]]])
    val, why = _bound(allpos, alltri, cell, 0.1)
    assert why[0] == WHY_BOUNDED
    # the plate's height (the washer is nearer where it lies: the bound holds, it is not tight)
    assert 0.01 <= val[0] < 0.01 * (1 + 1e-6)
    assert val[0] >= _dense_max(cell[0], allpos, alltri, rng)
    # the plate holed under the cell's middle: both components have a border over the cell
    centre = pos[tri].mean(axis=1)
    hole = np.argmin(np.linalg.norm(centre[:, :2] - [0.5, 0.3], axis=1))
    holed = np.concatenate([np.delete(tri, hole, axis=0), wtri_ + pos.shape[0]])
    val, why = _bound(allpos, holed, cell, 0.1)
    assert why[0] == WHY_BORDER and val[0] == np.inf


def test_steep_walls_under_the_cell_never_below_the_truth():
    """A ratchet: teeth rising gently to 0.08 and dropping over 1e-4 (walls nearly edge-on to the
    cells), over cells 0.03 below: the walls' and the tops' heights exceed the threshold, so
    their exact distances at the clipped corners are taken where smaller. Every value holds,
    and is below the vertical height of the tops."""
    rng = np.random.default_rng(6)
    xs = np.sort(np.concatenate([np.linspace(0.0, 1.0, 9), np.linspace(0.0, 1.0, 9)[1:-1] + 1e-4]))
    ys = np.linspace(0.0, 1.0, 9)
    x, y = np.meshgrid(xs, ys)
    # each tooth's top at x = k/8, its wall down to 0 at k/8 + 1e-4
    z = np.where(np.isclose(x * 8, np.round(x * 8), rtol=0, atol=1e-9) & (x > 0), 0.08, 0.0)
    pos = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    i = np.arange(x.size).reshape(x.shape)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    cpos, ctri = _grid(5, lambda x, y: 0 * x - 0.03, 0.05, 0.95)
    cells = cpos[ctri]
    val, why = _bound(pos, tri, cells, 0.1)
    assert (why == WHY_BOUNDED).all()
    for k in range(cells.shape[0]):
        assert val[k] >= _dense_max(cells[k], pos, tri, rng, 2000), k
    # every cell lies under a tooth's top, 0.11 above it: what the vertical heights alone give
    # (measured 0.86-0.91x of that with the exact distances)
    assert (val < 0.11).all(), val.max()


def test_random_loose_sheets_over_a_surface_never_below_dense_samples():
    """Pieces lying on a bumpy surface (small open sheets above or below it, some facing down,
    some crossing it), under cells: a piece with a border over a cell is left out, and every
    value given holds against dense brute force."""
    rng = np.random.default_rng(11)
    bounded = 0
    for trial in range(4):
        pos, tri = _grid(17, lambda x, y: 0.02 * np.sin(5 * x + trial) * np.cos(4 * y))
        parts_pos, parts_tri = [pos], [tri]
        n = pos.shape[0]
        for _ in range(12):
            lo = rng.uniform(0.05, 0.8, 2)
            size = rng.uniform(0.03, 0.2)
            lift = rng.uniform(-0.03, 0.03)
            tilt = rng.normal(0.0, 0.05, 2)
            k = int(rng.integers(2, 5))
            ppos, ptri = _grid(k, lambda x, y: lift + tilt[0] * (x - lo[0]) + tilt[1] * (y - lo[1]))
            ppos[:, :2] = lo + ppos[:, :2] * size
            if rng.random() < 0.3:
                ptri = ptri[:, ::-1]  # facing down
            parts_pos.append(ppos)
            parts_tri.append(ptri + n)
            n += ppos.shape[0]
        allpos, alltri = np.concatenate(parts_pos), np.concatenate(parts_tri)
        cpos, ctri = _grid(6, lambda x, y: 0 * x, 0.05, 0.95)
        cells = cpos[ctri] + rng.normal(scale=0.01, size=(ctri.shape[0], 3, 3))
        val, why = _bound(allpos, alltri, cells, 0.08)
        for i in np.flatnonzero(why == WHY_BOUNDED):
            bounded += 1
            assert val[i] >= _dense_max(cells[i], allpos, alltri, rng, 1500), (trial, i)
    # the pieces with a border are left out, not the surface: 198 of 200 cells bounded (97
    # when any border over a cell gave it up)
    assert bounded >= 150, bounded


def test_a_border_along_a_sliver_of_the_cell_is_kept():
    """The plate ends at x = 0.75 (an open rim) and the cell reaches 0.01 past it (an in-place
    level's chord over a hole's rim): the sliver beyond the rim is within its distance to the
    rim, and the cell is bounded by that. A cell reaching far past the rim is still given up."""
    rng = np.random.default_rng(8)
    pos, tri = _grid(9, lambda x, y: 0 * x)
    tri = tri[pos[tri].mean(axis=1)[:, 0] < 0.75]  # the plate up to x = 0.75
    cells = np.array([[[0.2, 0.2, 0.01], [0.76, 0.3, 0.01], [0.3, 0.7, 0.01]],
                      [[0.2, 0.2, 0.01], [0.95, 0.3, 0.01], [0.3, 0.7, 0.01]]])
    val, why = _bound(pos, tri, cells, 0.1)
    assert why[0] == WHY_BOUNDED
    dense = _dense_max(cells[0], pos, tri, rng)
    # the corner 0.01 past the rim and 0.01 above the plate: sqrt(2) * 0.01 from the rim
    assert dense <= val[0] <= 0.0142, (dense, val[0])
    assert why[1] == WHY_BORDER and val[1] == np.inf


def test_random_holes_never_below_dense_samples():
    """Bumpy surfaces with random triangles removed (holes, open rims), under noisy cells:
    borders are kept where the part of a cell beyond them is near them; every value holds."""
    rng = np.random.default_rng(12)
    kept_border = 0  # cells bounded
    for trial in range(4):
        pos, tri = _grid(17, lambda x, y: 0.02 * np.sin(6 * x + trial) * np.cos(5 * y))
        tri = tri[rng.random(tri.shape[0]) > 0.06]
        cpos, ctri = _grid(7, lambda x, y: 0 * x, 0.05, 0.95)
        cells = cpos[ctri] + rng.normal(scale=0.006, size=(ctri.shape[0], 3, 3))
        val, why = _bound(pos, tri, cells, 0.1)
        for i in np.flatnonzero(why == WHY_BOUNDED):
            assert val[i] >= _dense_max(cells[i], pos, tri, rng, 1500), (trial, i)
        kept_border += int((why == WHY_BOUNDED).sum())
    # 120 of the 288 cells bounded (95 when every border over a cell left its piece out)
    assert kept_border >= 110, kept_border
