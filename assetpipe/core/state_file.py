"""A build's record in its output folder (``OUT/.assetpipe/state.json``), read-only.

The orchestrator (``assetpipe/state.py``) owns and writes the record; tools below it, such as the
validator looking for the source of a built model, only read it through this module.
"""

from __future__ import annotations

import json
from pathlib import Path

from assetpipe.core.writer import STATE_DIR


def read_json_dict(path: Path) -> dict:
    """The JSON object in ``path``; ``{}`` when it is missing, unreadable or not an object."""
    try:
        data = json.loads(Path(path).read_bytes())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def source_of(out_dir: Path, model_id: str) -> Path | None:
    """The source file the build in ``out_dir`` made ``model_id`` from (None if unknown)."""
    data = read_json_dict(Path(out_dir) / STATE_DIR / "state.json")
    assets = data.get("assets")
    for key, entry in (assets.items() if isinstance(assets, dict) else ()):
        if isinstance(entry, dict) and entry.get("id") == model_id:
            source = entry.get("source", key)
            return Path(source) if isinstance(source, str) else None
    return None
