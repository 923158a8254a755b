"""Validating built models: one in this process, or a batch in a crash-isolated renderer
subprocess (``worker.py``). The checks themselves live in ``validate.py``; this module is the
runner, so the worker and the checks never import each other in a circle.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Iterable

from .results import ValidateOptions, ValidationResult
from .validate import run_checks
from .worker import WorkerPool


def validate_model(model_json: Path | str, options: ValidateOptions | None = None,
                   isolate: bool = True) -> ValidationResult:
    """Validate one built model (``OUT/ID.json``).

    ``isolate=True`` (the default) renders in a subprocess with ``options.timeout_s``, so a
    driver crash becomes a failed result instead of killing the caller. ``isolate=False``
    uses this process's shared renderer (tests, the worker itself).
    """
    options = options or ValidateOptions()
    if isolate:
        return validate_batch([model_json], options)[0]
    from .session import shared_renderer  # noqa: PLC0415 - vulkan is imported when a model is rendered

    t0 = time.perf_counter()
    renderer = shared_renderer(options.width, options.height, validation=options.validation_layer,
                               shader_cache=Path(options.shader_cache) if options.shader_cache else None)
    setup = time.perf_counter() - t0
    result = run_checks(Path(model_json), options, renderer)
    result.timings["setup"] = setup
    return result


def validate_batch(paths: Iterable[Path | str], options: ValidateOptions | None = None,
                   isolate: bool = True, progress: Any = None) -> list[ValidationResult]:
    """Validate many built models with one long-lived renderer subprocess.

    Device set-up happens once; each asset has ``options.timeout_s``. If the subprocess dies
    (driver crash) or times out, that asset fails with a clear message and a fresh
    subprocess continues the batch. ``progress(result)`` is called after each asset.
    """
    options = options or ValidateOptions()
    paths = [Path(p) for p in paths]
    if not isolate:
        out = []
        for p in paths:
            r = validate_model(p, options, isolate=False)
            out.append(r)
            if progress:
                progress(r)
        return out
    with WorkerPool(options) as pool:
        out = []
        for p in paths:
            r = pool.validate(p)
            out.append(r)
            if progress:
                progress(r)
        return out
