"""GLSL 450 -> SPIR-V with ``glslangValidator -V``, cached by the content digest of the source.

The cache lives outside the repository, under the assetpipe cache root (``shaders/``), or
a directory passed in. A cached module is named after the SHA-256 of (stage, source), so an
edited shader is recompiled and an unchanged one never is.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from assetpipe.core.errors import RenderError

from ._vk import INSTALL_HINT, cache_root

# the GLSL sources: a data package of their own (pyproject.toml lists assetpipe.renderer.glsl;
# named apart from this module, which a package "shaders" beside it would share its name with)
SHADER_DIR = Path(__file__).resolve().parent / "glsl"


def default_cache_dir() -> Path:
    """``shaders/`` under the assetpipe cache root (see :func:`renderer._vk.cache_root`)."""
    return cache_root() / "shaders"


def compile_glsl(source_path: Path, cache_dir: Path | None = None, defines: tuple[str, ...] = ()) -> bytes:
    """The SPIR-V words of ``source_path`` (stage from its extension), compiled once per content
    and set of ``defines`` (preprocessor macros, ``-D``)."""
    source = Path(source_path).read_bytes()
    stage = Path(source_path).suffix.lstrip(".")
    digest = hashlib.sha256(stage.encode() + b"\0" + source + b"\0" + " ".join(defines).encode()).hexdigest()
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cached = cache / f"{Path(source_path).stem}-{stage}-{digest[:32]}.spv"
    if cached.is_file():
        return cached.read_bytes()
    tool = shutil.which("glslangValidator")
    if tool is None:
        raise RenderError(f"glslangValidator is not on PATH: {INSTALL_HINT}")
    cache.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".spv", dir=cache)
    os.close(fd)
    try:
        proc = subprocess.run([tool, "-V", "-S", stage, *(f"-D{d}" for d in defines), "-o", tmp, str(source_path)],
                              capture_output=True, text=True, timeout=60)
        if proc.returncode != 0:
            raise RenderError(f"glslangValidator failed on {source_path}:\n{proc.stdout}{proc.stderr}")
        os.replace(tmp, cached)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return cached.read_bytes()


def shader_path(name: str) -> Path:
    """The packaged shader ``renderer/glsl/<name>``."""
    return SHADER_DIR / name
