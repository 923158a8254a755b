"""Shared fixtures: where the corpus is, and small helpers.

The corpus location comes from one setting, ``$ASSETPIPE_CORPUS`` (a folder holding ``models/``
and ``nasty/``), by default ``../shared/corpus`` beside the repository. Where it is absent, every
test that asks for the ``corpus`` fixture is set aside (deselected) and one line at the end of
the run says how many and how to get the corpus; the rest of the suite runs on fixtures in ``tests/data``,
``examples/`` and meshes the tests generate.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
# The shared corpus sits beside the checkout (../shared/corpus); ASSETPIPE_CORPUS overrides.
CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS") or REPO.parent / "shared" / "corpus")
MODELS = CORPUS / "models"
NASTY = CORPUS / "nasty"
CORPUS_PRESENT = MODELS.is_dir() and NASTY.is_dir()
CORPUS_MISSING = (f"corpus tests skipped (deselected): no corpus at {CORPUS} (set ASSETPIPE_CORPUS to a folder with "
                  "models/ and nasty/; its MANIFEST.tsv names each file's public source: README.md, 'The test corpus')")


def pytest_report_header(config):
    return f"corpus: {CORPUS}" if CORPUS_PRESENT else None


def pytest_collection_modifyitems(config, items):
    """Without the corpus, the tests that need it are set aside (one line says so, once)."""
    if CORPUS_PRESENT:
        return
    need = [it for it in items if "corpus" in getattr(it, "fixturenames", ())]
    if need:
        config.hook.pytest_deselected(items=need)
        items[:] = [it for it in items if "corpus" not in getattr(it, "fixturenames", ())]
        config._assetpipe_corpus_skipped = len(need)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    n = getattr(config, "_assetpipe_corpus_skipped", 0)
    if n:
        terminalreporter.write_line(f"{n} {CORPUS_MISSING}")


@pytest.fixture(scope="session")
def corpus() -> Path:
    if not CORPUS_PRESENT:  # only reached by a test asking for it lazily (request.getfixturevalue)
        pytest.skip(CORPUS_MISSING)
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


@pytest.fixture(scope="session")
def s3_server():
    """One real S3-compatible server for the session (moto's server mode, its own process on
    127.0.0.1 at a free port, one bucket; tests/farm_fixtures.py), stopped at the end. While it
    runs, the AWS_* variables in os.environ point botocore at it. Tests use their own prefixes."""
    from farm_fixtures import S3Server

    server = S3Server()
    yield server
    server.stop()
