"""Step versions, in one numpy-free module so the no-op build path can read them cheaply.

Bump a step's version when its output changes for the same inputs and options: it is part of
that step's cache key, so every cached result of the old version is rebuilt.
"""

IMPORT = 2  # 2: geometry-only blob
MESH = 1
LOD = 2  # 2: meshopt SimplifySparse (unreferenced twins no longer lock vertices)
TEXTURE = 1
ENCODE = 1
FORMAT = 1  # docs/FORMAT.md: the sidecar's formatVersion

STEP_VERSIONS = {"import": IMPORT, "mesh": MESH, "lod": LOD, "texture": TEXTURE, "encode": ENCODE,
                 "format": FORMAT}


def library_versions() -> dict:
    """Versions of the libraries whose output the steps depend on (part of every key)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for dist in ("numpy", "pygltflib", "meshoptimizer", "DracoPy", "opencv-python-headless", "pillow",
                 "point-cloud-utils", "fast-simplification"):
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = None
    return out
