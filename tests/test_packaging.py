"""The wheel's configuration (pyproject.toml [tool.setuptools]) covers the source tree: every
folder the installed packages hold is a listed package (setuptools warns at every install about
a folder it sees as a package but is not told about), and every data file in one is installed."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _folder(name: str, package_dir: dict) -> Path:
    """The source folder of dotted package ``name`` (the longest package-dir entry above it)."""
    for prefix in sorted(package_dir, key=len, reverse=True):
        if name == prefix or name.startswith(prefix + "."):
            rest = name[len(prefix):].lstrip(".")
            return ROOT / package_dir[prefix] / Path(*rest.split(".")) if rest else ROOT / package_dir[prefix]
    return ROOT / Path(*name.split("."))


def test_every_folder_of_the_installed_packages_is_a_listed_package():
    cfg = _config()
    listed = set(cfg["packages"])
    folders = {_folder(p, cfg["package-dir"]).resolve(): p for p in listed}
    missing = []
    for name in listed:
        for sub in _folder(name, cfg["package-dir"]).iterdir():
            if sub.is_dir() and sub.name != "__pycache__" and sub.resolve() not in folders \
                    and any(f.is_file() for f in sub.iterdir()):
                missing.append(f"{name}.{sub.name}")
    assert not missing, f"folders setuptools would warn about (not in packages): {missing}"


def test_every_data_file_in_a_package_folder_is_installed():
    cfg = _config()
    data = cfg.get("package-data", {})
    left = []
    for name in cfg["packages"]:
        for f in _folder(name, cfg["package-dir"]).iterdir():
            if f.is_file() and f.suffix not in (".py", ".pyc") and \
                    not any(fnmatch.fnmatch(f.name, pat) for pat in data.get(name, [])):
                left.append(f"{name}: {f.name}")
    assert not left, f"data files the wheel leaves out: {left}"
    assert data["assetpipe.renderer.glsl"] and (ROOT / "renderer" / "glsl" / "mesh.frag").is_file()
