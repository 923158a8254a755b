"""The one exception tree of assetpipe.

    AssetpipeError                 anything assetpipe raises on purpose
    +-- AssetError                 the *input* is bad: the user's problem, reported in one line
    |   +-- MissingFileError       a referenced file (.bin, image, .mtl) is absent
    |   +-- UnsupportedError       a required extension / feature we cannot decode
    |   +-- InvalidGeometryError   NaN/Inf positions, indices out of range, ...
    |   +-- InvalidTextureError    an image that cannot be decoded or is too large
    |   +-- SceneError             a scene file that is wrong
    +-- ConfigError                bad options or command-line use
    +-- CacheError                 the cache store is unusable (permissions, disk full)
    +-- RenderError                the Vulkan renderer could not run (missing driver, crash)

An exception that is *not* an AssetpipeError is a bug in the pipeline: the build reports it
with a traceback and the words "internal error", never as the user's fault.
"""

from __future__ import annotations

from pathlib import Path


class AssetpipeError(Exception):
    """Base of every error assetpipe raises deliberately."""


class AssetError(AssetpipeError):
    """A bad asset. ``str(err)`` is one line: ``<file>: <problem>``."""

    def __init__(self, path: str | Path | None, problem: str):
        self.path = str(path) if path is not None else None
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)

    def __reduce__(self):  # survives pickling between build worker processes
        return (self.__class__, (self.path, self.problem))


class MissingFileError(AssetError):
    pass


class UnsupportedError(AssetError):
    pass


class InvalidGeometryError(AssetError):
    pass


class InvalidTextureError(AssetError):
    pass


class SceneError(AssetError):
    pass


class ConfigError(AssetpipeError):
    pass


class CacheError(AssetpipeError):
    pass


class RenderError(AssetpipeError):
    pass
