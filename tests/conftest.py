"""Shared fixtures: where the corpus is, and small helpers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
# The shared corpus sits beside the checkout (../shared/corpus); ASSETPIPE_CORPUS overrides.
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus"))
MODELS = CORPUS / "models"
NASTY = CORPUS / "nasty"


@pytest.fixture(scope="session")
def corpus() -> Path:
    if not MODELS.is_dir():
        pytest.fail(f"the shared corpus is missing at {CORPUS} (set ASSETPIPE_CORPUS)")
    return CORPUS


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory):
    """Builds in tests use a cache of their own, never the user's."""
    old = os.environ.get("ASSETPIPE_CACHE")
    os.environ["ASSETPIPE_CACHE"] = str(tmp_path_factory.mktemp("assetpipe-cache"))
    yield
    if old is None:
        os.environ.pop("ASSETPIPE_CACHE", None)
    else:
        os.environ["ASSETPIPE_CACHE"] = old
