"""The only code that writes build outputs: atomic file replacement.

Each file is written to a temporary name in the destination folder, flushed, and renamed over
the final name (``os.replace`` is atomic on POSIX), so a reader — or a build killed at any
moment — never sees a partial file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_outputs(out_dir: Path, files: dict[str, bytes]) -> list[Path]:
    """Write ``relative name -> bytes`` under ``out_dir``; returns the paths, in the given order.

    A file whose current content is already identical is left untouched (its mtime too).
    """
    written = []
    for rel, data in files.items():
        path = out_dir / rel
        try:
            if path.stat().st_size == len(data) and path.read_bytes() == data:
                written.append(path)
                continue
        except FileNotFoundError:
            pass
        write_atomic(path, data)
        written.append(path)
    return written
