"""Loading the Vulkan binding with lavapipe selected, and turning loader problems into RenderError.

Import :func:`load_vulkan` instead of ``import vulkan``: it sets the environment the Vulkan
loader and Mesa read (``VK_DRIVER_FILES`` pointing at lavapipe's ICD, a Mesa shader cache and
a validation-layer cache outside the user's home) *before* the binding dlopens
``libvulkan.so.1``, and reports a missing loader or driver with the Debian packages to install.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType

from assetpipe.core.errors import RenderError

LAVAPIPE_ICD = Path("/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
DEBIAN_PACKAGES = "mesa-vulkan-drivers libvulkan1 vulkan-validationlayers glslang-tools spirv-tools"
INSTALL_HINT = f"install the Debian packages {DEBIAN_PACKAGES}"

_vk: ModuleType | None = None


def cache_root() -> Path:
    """The assetpipe cache root, the build cache's: ``$ASSETPIPE_CACHE``, else
    ``$XDG_CACHE_HOME/assetpipe``, else ``~/.cache/assetpipe``."""
    from assetpipe.cache.store import default_cache_dir  # noqa: PLC0415

    return default_cache_dir()


def renderer_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment variables the renderer process needs (merged over ``base``).

    * ``VK_DRIVER_FILES`` (and the older ``VK_ICD_FILENAMES``): lavapipe only, so a machine with
      a GPU renders exactly what the tests expect.
    * ``MESA_SHADER_CACHE_DIR``: Mesa's shader cache under the assetpipe cache, not in ``~``.
    * ``XDG_CACHE_HOME``: where the validation layer writes its cache; kept if set, else put
      under the assetpipe cache so nothing lands in ``~/.cache`` beside it.
    """
    env = dict(os.environ if base is None else base)
    icd = env.get("ASSETPIPE_VK_ICD", str(LAVAPIPE_ICD))
    env["VK_DRIVER_FILES"] = icd
    env["VK_ICD_FILENAMES"] = icd
    env.setdefault("MESA_SHADER_CACHE_DIR", str(cache_root() / "mesa_shader_cache"))
    env.setdefault("ASSETPIPE_CACHE", str(cache_root()))  # the worker resolves the same root
    env.setdefault("XDG_CACHE_HOME", str(cache_root() / "xdg"))
    return env


def load_vulkan() -> ModuleType:
    """Import and return the ``vulkan`` binding, lavapipe selected.

    Raises :class:`RenderError` naming the Debian packages when the loader or lavapipe is
    missing.
    """
    global _vk
    if _vk is not None:
        return _vk
    env = renderer_env()
    icd = Path(env["VK_DRIVER_FILES"])
    if not icd.is_file():
        raise RenderError(f"lavapipe's Vulkan ICD {icd} is absent: {INSTALL_HINT}")
    try:
        Path(env["MESA_SHADER_CACHE_DIR"]).mkdir(parents=True, exist_ok=True)
    except OSError:
        env["MESA_SHADER_CACHE_DISABLE"] = "true"
        os.environ["MESA_SHADER_CACHE_DISABLE"] = "true"
    for key in ("VK_DRIVER_FILES", "VK_ICD_FILENAMES", "MESA_SHADER_CACHE_DIR"):
        os.environ[key] = env[key]
    try:
        import vulkan  # noqa: PLC0415  (dlopens libvulkan.so.1 here)
    except OSError as exc:
        raise RenderError(f"cannot load the Vulkan loader libvulkan.so.1 ({exc}): {INSTALL_HINT}") from exc
    except ImportError as exc:
        raise RenderError(f"the Python package 'vulkan' is not installed ({exc}); "
                          f"also {INSTALL_HINT}") from exc
    _vk = vulkan
    return vulkan
