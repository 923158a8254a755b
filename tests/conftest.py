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
