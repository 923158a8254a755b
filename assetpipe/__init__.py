"""assetpipe: glTF 2.0 and OBJ to an engine-ready format, with LODs, premipped textures and
validation on lavapipe. Importing this package is light: it imports nothing heavy (no numpy);
the Python API (``assetpipe.build``, ``assetpipe.validate``, ``assetpipe.load``: assetpipe/api.py) is
imported on first use.

One installed name holds four layers (docs/ARCHITECTURE.md): ``assetpipe.core`` (basics),
``assetpipe.cache`` and ``assetpipe.pipelines`` (the store and the pure steps),
``assetpipe.renderer`` (Vulkan loader and validator), and this package's own modules
(orchestration and the CLI) on top.
"""

import os as _os
import sys as _sys

__version__ = "0.1.0"

# The repository keeps pipelines/, cache/ and renderer/ at its top level; the wheel installs them
# as assetpipe.pipelines, assetpipe.cache and assetpipe.renderer (pyproject's package-dir). When
# this package runs from a source tree (a checkout on sys.path, a worktree, an editable install),
# those subpackages are found beside it.
_root = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if (not _os.path.isdir(_os.path.join(_os.path.dirname(_os.path.abspath(__file__)), "pipelines"))
        and _os.path.isfile(_os.path.join(_root, "pipelines", "__init__.py"))):
    __path__.append(_root)  # type: ignore[name-defined]  # noqa: F821
del _root

# The Python API (assetpipe/api.py), imported on first use (PEP 562), so ``import assetpipe`` stays
# light: ``assetpipe.build(...)``, ``assetpipe.validate(...)``, ``assetpipe.load(...)``.
_API = frozenset({"validate", "load", "LoadedModel", "LoadedMesh", "BuildOptions", "BuildReport", "AssetResult",
                  "MeshOptions", "LodOptions", "TextureOptions", "ValidateOptions", "ValidationResult",
                  "AssetError", "AssetpipeError", "usable_cpus"})


def __getattr__(name: str):
    if name in _API:
        from assetpipe import api

        return getattr(api, name)
    if name == "build":  # the orchestration module, callable as the API's build (below)
        import assetpipe.build

        return assetpipe.build
    raise AttributeError(f"module 'assetpipe' has no attribute {name!r}")


class _BuildModule(type(_os)):
    """``assetpipe.build`` names both the orchestration module (``assetpipe/build.py``) and the
    API call; calling the module runs :func:`assetpipe.api.build`."""

    def __call__(self, inputs, out, **options):
        from assetpipe.api import build

        return build(inputs, out, **options)


class _Package(type(_os)):
    def __setattr__(self, name, value):
        # the import system binds each submodule on its package as it loads: give assetpipe.build its call
        if name == "build" and type(value) is type(_os):
            value.__class__ = _BuildModule
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
