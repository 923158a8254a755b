"""Step versions, in one numpy-free module so the no-op build path can read them cheaply.

Bump a step's version when its output changes for the same inputs and options: it is part of
that step's cache key, so every cached result of the old version is rebuilt.
"""

IMPORT = 4  # 2: geometry-only blob; 3: earcut for concave polygons, degenerate and repeated OBJ faces dropped (#13);
           # 4: meta has the bounding-box centre (--recenter)
MESH = 5  # 5: inside-out closed meshes warned about; 2: non-finite UVs cleaned before tangents are derived; 3: float32 positions, duplicates;
          # 4: generated tangents are MikkTSpace (pipelines/tangents.py), w in glTF's convention
LOD = 27  # 2: meshopt SimplifySparse; 3: stalled steps try pruning/sloppy at a 1.1x slack; 4: recorded Hausdorff is an upper bound;
        # 5: merged meshes, affine copies once, duplicates dropped, best of chained/direct, error budget
        # 6: candidates ranked on removed vertices; the error records its lower value and convergence
        # 7: the bound's kernels compiled (numba): same formulas, float64 rounding may differ in the last digits
        # 8: nearest triangles from our float64 BVH (fcpw's float32 test misjudged slivers)
        # 9: options for a positions-only candidate (LodOptions.geometry_candidate) and a locked
        #    re-simplification (lock_fraction), both off by default
        # 10: the bound tries the cell's known triangles before querying its centroid
        # 11: the height-field (patch) bound settles cells over one sheet of the other mesh
        # 12: the recorded measurement seeds its bound with fewer samples (LodOptions.bound_samples_*): RMS estimate changes
        # 13: the pair bound is tried before the height field (recorded bounds within the tolerance, some differ)
        # 14: the estimator's value of a chosen level seeds its bound; the estimator works in the reference's frame
        # 15: a model's distinct meshes can share each level's triangle budget by error (LodOptions.balance_meshes, off by default)
        # 16: no mesh's share below 3/4 of its even share (lod_model.SHARE_KEEP)
        # 17: balance_meshes on by default, with a facing floor (no thin part folded flat below its even share)
        # 18: a balanced level whose curves stall above its budget gives every mesh its even share
        # 19: a candidate with moved vertices (meshoptimizer 1.3 simplifyWithUpdate, LodOptions.move_vertices): such levels get their own vertex rows
        # 20: meshes whose materials are equal in content (all but the name) are merged, as gltfpack does
        # 21: the height field gathers only triangles within its radius of the cell's plane (recorded bounds
        #     equal or up to 1.3% tighter); a cell with corners within rounding of each other no longer stops a chain
        # 22: the bound settles within 2^-23 of the diagonal (was 1e-12) and the pair bound also cuts two coplanar
        #     triangles along a wall of one (T-junctions on flat faces): levels exactly on level 0 converge (the
        #     corpus's levels and bounds unchanged; the generated CAD boxes' bounds 2.4e-6 unconverged -> 1e-8);
        #     two coplanar triangles of a cell's known ones are paired too, and the height field is tried on
        #     every cell (also children of a cell it failed on): 12 corpus bounds up to 0.9% tighter
        # 23: a moved level's rows the simplifier did not move are level 0's rows bit for bit (were their float32
        #     roundings): written so, and shared with level 0 by the bound and the estimator
        # 24: the recorded measurement draws M/16 area samples a side (was M/4): RMS estimates change, bounds do not
        # 25: the height field leaves out the components of its sheet with a border or fold over the cell and
        #     bounds a triangle higher than the threshold by its exact distance where smaller (recorded bounds change
        #     within the tolerance)
        # 26: the height field keeps a border over the cell where the part of the cell beyond it is near it
        #     (uncovered points there are bounded by their distance to it): recorded bounds change within the tolerance
        # 27: the height field's patch is grown first from the target triangles near the cell's corners across edges
        #     two triangles share (a subset of the BVH's patch; the BVH's only where that is empty or covers too
        #     little): recorded bounds change within the tolerance
TEXTURE = 4  # 2: --texture-compression (BC/ETC2 blocks), zstd supercompression; 3: BC7 tries 8 mode-1 partitions; 4: BC7 4 partitions without least squares, zstd level 1, ETC2/EAC from etcpak's SIMD build
ENCODE = 3  # 2: stats count duplicate triangles; positionOffset; 3: a scene that skips levels keeps only the rows its kept levels use
FORMAT = 1  # docs/FORMAT.md: the sidecar's formatVersion

STEP_VERSIONS = {"import": IMPORT, "mesh": MESH, "lod": LOD, "texture": TEXTURE, "encode": ENCODE,
                 "format": FORMAT}


_DISTS = ("numpy", "meshoptimizer", "DracoPy", "opencv-python-headless", "pillow",
          "numba", "fast-simplification", "mapbox_earcut", "etcpak", "zstandard")
_cached: dict | None = None
_memo_dir = None  # the build's cache folder (use_cache_dir); None: the default one


def use_cache_dir(path) -> None:
    """Remember library versions in ``path`` (the build's cache), not the default cache folder:
    a build given ``--cache`` writes nothing outside it and ``-o``."""
    global _memo_dir
    _memo_dir = path


def _site_dirs() -> list[str]:
    import site
    import sys

    dirs = [p for p in sys.path if p.endswith("site-packages")]
    try:
        dirs += site.getsitepackages()
    except AttributeError:  # pragma: no cover - virtualenvs without it
        pass
    return sorted(set(dirs))


def library_versions() -> dict:
    """Versions of the libraries whose output the steps depend on (part of every key).

    Reading package metadata costs about 20 ms, so the answer is remembered per process and on
    disk beside the cache, keyed by the modification times of the site-packages folders
    (installing, upgrading or removing a package changes them)."""
    global _cached
    if _cached is None:
        _cached = {**_python_versions(), "meshoptimizer-wasm": _wasm_version()}
    return dict(_cached)


def _wasm_version() -> str | None:
    """meshoptimizer's WASM simplifier (npm, run by wasmtime: pipelines/meshopt_wasm.py), or
    None when it is not installed: levels with moved vertices exist only with it."""
    from assetpipe.pipelines import meshopt_wasm

    return meshopt_wasm.version()


def _python_versions() -> dict:
    import json
    import os
    from pathlib import Path

    from assetpipe.cache.store import default_cache_dir

    stamp = []
    for d in _site_dirs():
        try:
            stamp.append([d, os.stat(d).st_mtime_ns])
        except OSError:
            pass
    memo = (Path(_memo_dir) if _memo_dir is not None else default_cache_dir()) / "library-versions.json"
    try:
        data = json.loads(memo.read_bytes())
        if data.get("stamp") == stamp and set(data.get("versions", {})) == set(_DISTS):
            return dict(data["versions"])
    except (OSError, ValueError, AttributeError):
        pass
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for dist in _DISTS:
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = None
    try:
        memo.parent.mkdir(parents=True, exist_ok=True)
        tmp = memo.with_name(f".{memo.name}.{os.getpid()}")
        tmp.write_text(json.dumps({"stamp": stamp, "versions": out}))
        os.replace(tmp, memo)
    except OSError:
        pass
    return dict(out)
