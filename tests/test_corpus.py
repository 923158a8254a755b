"""Every model of ../shared/corpus/models builds and loads with a strict seed loader."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from assetpipe.cli import main
from seed_loader import load_seed_model

pytestmark = pytest.mark.corpus


@pytest.fixture(scope="module")
def corpus_build(corpus, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("corpus")
    r = CliRunner().invoke(main, ["build", str(corpus / "models"), "-o", str(tmp / "out"),
                                  "--json", str(tmp / "report.json")])
    return r, tmp / "out", json.loads((tmp / "report.json").read_text())


def test_every_corpus_model_builds(corpus_build, corpus):
    r, out, report = corpus_build
    failed = [a for a in report["assets"] if a["status"] not in ("built", "cached")]
    assert not failed, failed
    n_models = len([p for p in (corpus / "models").rglob("*") if p.suffix.lower() in (".gltf", ".glb", ".obj")])
    assert len(report["assets"]) == n_models
    assert r.exit_code == 0


def test_every_built_model_satisfies_the_seed_contract(corpus_build):
    _, out, report = corpus_build
    for a in report["assets"]:
        model = load_seed_model(out / f"{a['id']}.json")
        for m in model.meshes:
            assert np.isfinite(m.positions).all() and np.isfinite(m.uvs).all(), (a["id"], m.id)
            assert m.indices.size and int(m.indices.max()) < m.positions.shape[0], (a["id"], m.id)
        r = CliRunner().invoke(main, ["inspect", str(out / f"{a['id']}.json")])
        assert r.exit_code == 0, r.output


@pytest.mark.vulkan
def test_every_built_corpus_model_validates_on_lavapipe(corpus_build):
    """assetpipe validate with every check on (validation layer, silhouette, source, LODs, mips)."""
    from assetpipe.renderer.batch import validate_batch

    _, out, report = corpus_build
    paths = [out / f"{a['id']}.json" for a in report["assets"]]
    results = validate_batch(paths)
    assert len(results) == len(paths)
    failed = {r.model: r.failures() for r in results if not r.passed}
    assert not failed, failed
