"""assetpipe: glTF 2.0 and OBJ to an engine-ready format, with LODs, premipped textures and
validation on lavapipe. Importing this package is light: it imports nothing heavy (no numpy).

One installed name holds four layers (docs/ARCHITECTURE.md): ``assetpipe.core`` (basics),
``assetpipe.cache`` and ``assetpipe.pipelines`` (the store and the pure steps),
``assetpipe.renderer`` (Vulkan loader and validator), and this package's own modules
(orchestration and the CLI) on top.
"""

import os as _os

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
