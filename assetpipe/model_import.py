"""Choosing the importer for a source file by its suffix."""

from __future__ import annotations

from pathlib import Path

from assetpipe.core.errors import AssetError
from assetpipe.pipelines.model import ImportedModel


def import_model(source: Path, budgets=None) -> ImportedModel:
    """Import ``source``; ``budgets``: a :class:`pipelines.budgets.InputBudgets` (None: the defaults)."""
    suffix = source.suffix.lower()
    if suffix in (".gltf", ".glb"):
        from assetpipe.pipelines.import_gltf import import_gltf
        return import_gltf(source) if budgets is None else import_gltf(source, budgets)
    if suffix == ".obj":
        from assetpipe.pipelines.import_obj import import_obj
        return import_obj(source) if budgets is None else import_obj(source, budgets)
    raise AssetError(source, f"unsupported file type {suffix!r}")
