"""MikkTSpace tangents (the frame glTF names for normal maps), vectorised in numpy.

No binding installs here: ``pymikktspace`` 0.3.0 (the only one on PyPI, last release 2021) fails
to build with Cython 3 (its callbacks lack ``noexcept``) and, with Cython < 3, on Python 3.11
(``longintrepr.h`` is gone). This is a port of Morten Mikkelsen's reference ``mikktspace.c``
(the code Blender, xNormal and most glTF exporters call) for triangles, with its defaults
(angular threshold 180 degrees, so no group is split by angle):

1. vertices are welded when position, normal and UV are all equal (the reference's
   ``GenerateSharedVerticesIndexList``);
2. per triangle, the UV-gradient tangent ``vOs`` is normalised and signed by the triangle's UV
   orientation (``fSignedAreaSTx2 > 0``: orientation preserving); a triangle with zero UV area
   adds nothing, a triangle with two equal welded corners is skipped (the reference's
   degenerate triangles);
3. per corner, ``vOs`` is projected into the plane of that corner's normal, normalised and
   weighted by the corner's angle (its two edges projected into the same plane): ``EvalTspace``;
4. a welded vertex's corners are grouped by orientation (``Build4RuleGroups``); a group's tangent
   is its normalised weighted sum, its handedness -1 when orientation preserving in glTF's UVs
   (V down; the reference's +1 in V-up UVs), else +1.

Where the reference differs: it writes one tangent per triangle corner, so a vertex whose fan
holds both UV orientations (a mirrored UV seam sharing one vertex), or two fans not joined by
an edge (a bow-tie), gets two tangents there; an indexed mesh keeps one, the group with the
larger summed corner angle. Vertices no triangle gives a tangent (zero UV area all round,
unused) get an arbitrary unit vector perpendicular to the normal, w = +1.
"""

from __future__ import annotations

import numpy as np


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows / |rows| where nonzero else the zero row, nonzero mask)."""
    n = np.linalg.norm(v, axis=1)
    ok = n > 0.0
    return np.where(ok[:, None], v / np.where(ok, n, 1.0)[:, None], 0.0), ok


def _weld(pos: np.ndarray, nrm: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) int: one id per distinct (position, normal, UV) as float32 bit patterns."""
    key = np.ascontiguousarray(np.hstack([pos, nrm, uv]).astype(np.float32))
    rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, inverse = np.unique(rows, return_inverse=True)
    return inverse.reshape(-1).astype(np.int64)


def perpendicular(normals: np.ndarray) -> np.ndarray:
    """(N, 3) an arbitrary unit vector perpendicular to each (unit) normal."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    out, _ = _unit(np.cross(normals, helper))
    return out


def mikktspace_tangents(positions: np.ndarray, indices: np.ndarray, normals: np.ndarray,
                        uv: np.ndarray) -> np.ndarray:
    """(N, 4) float64 MikkTSpace tangents: xyz unit, w = handedness (+1/-1), glTF convention
    (bitangent = cross(normal, tangent.xyz) * w, UVs as stored in glTF).

    positions (N, 3), normals (N, 3) unit, uv (N, 2), indices (M, 3) int, each < N."""
    pos = np.asarray(positions, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    tex = np.asarray(uv, dtype=np.float64)
    tris = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
    n = pos.shape[0]
    out = np.hstack([perpendicular(nrm), np.ones((n, 1))])
    if n == 0 or tris.shape[0] == 0:
        return out
    weld = _weld(pos, nrm, tex)
    wt = weld[tris]
    keep = (wt[:, 0] != wt[:, 1]) & (wt[:, 1] != wt[:, 2]) & (wt[:, 0] != wt[:, 2])
    tris, wt = tris[keep], wt[keep]
    p = pos[tris]  # (M, 3, 3)
    t = tex[tris]  # (M, 3, 2)
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    t21, t31 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area = t21[:, 0] * t31[:, 1] - t21[:, 1] * t31[:, 0]
    orient = area > 0.0
    v_os = t31[:, 1:2] * d1 - t21[:, 1:2] * d2
    v_os, _ = _unit(v_os)
    v_os *= np.where(orient, 1.0, -1.0)[:, None]
    v_os[area == 0.0] = 0.0  # no UV area: no direction (the reference leaves vOs zero)

    corner_v = tris.reshape(-1)                      # (3M,) original vertex of each corner
    corner_n = nrm[corner_v]
    tri_os = np.repeat(v_os, 3, axis=0)
    proj, _ = _unit(tri_os - corner_n * np.einsum("ij,ij->i", corner_n, tri_os)[:, None])
    # the corner's angle, its edges projected into the normal's plane (EvalTspace)
    here = p.reshape(-1, 3)
    prev = p[:, [2, 0, 1]].reshape(-1, 3)
    nxt = p[:, [1, 2, 0]].reshape(-1, 3)
    e1, e2 = prev - here, nxt - here
    e1, _ = _unit(e1 - corner_n * np.einsum("ij,ij->i", corner_n, e1)[:, None])
    e2, _ = _unit(e2 - corner_n * np.einsum("ij,ij->i", corner_n, e2)[:, None])
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", e1, e2), -1.0, 1.0))
    contributes = np.repeat(area != 0.0, 3)

    # groups: (welded vertex, orientation)
    group = wt.reshape(-1) * 2 + np.repeat(orient, 3)
    n_groups = int(weld.max() + 1) * 2
    acc = np.stack([np.bincount(group, weights=angle * proj[:, k], minlength=n_groups) for k in range(3)], axis=1)
    weight = np.bincount(group, weights=np.where(contributes, angle, 0.0), minlength=n_groups)
    tangent, ok = _unit(acc)

    # each original vertex: its welded vertex's heavier group among those that gave a direction
    used = np.zeros(n, dtype=bool)
    used[corner_v[contributes]] = True
    w_pos, w_neg = weight[weld * 2 + 1], weight[weld * 2]
    pick = np.where(w_pos >= w_neg, weld * 2 + 1, weld * 2)
    good = used & ok[pick]
    t_xyz = tangent[pick]
    # per-vertex normals may differ from the welded group's (welding includes the normal): no-op,
    # but keep the result exactly perpendicular to the vertex normal as the reference's output is
    t_xyz, ok2 = _unit(t_xyz - nrm * np.einsum("ij,ij->i", nrm, t_xyz)[:, None])
    good &= ok2
    out[good, :3] = t_xyz[good]
    # glTF stores V downwards (the reference's v is upwards): an orientation-preserving group in
    # glTF UVs is a mirrored one in the reference's, so its w is -1 (matches Avocado's exporter)
    out[good, 3] = np.where(pick[good] % 2 == 1, -1.0, 1.0)
    return out
