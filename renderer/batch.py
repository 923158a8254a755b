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
                   isolate: bool = True, progress: Any = None, jobs: int = 1,
                   baseline: dict[str, Any] | None = None, stats: dict[str, Any] | None = None,
                   ) -> list[ValidationResult]:
    """Validate many built models with long-lived renderer subprocesses.

    Device set-up happens once per subprocess; ``jobs`` subprocesses (each its own Vulkan
    device) take models from one queue, so a batch runs in parallel. Each asset has
    ``options.timeout_s``. If a subprocess dies (driver crash) or times out, that asset fails with
    a clear message and a fresh subprocess continues. ``progress(result)`` is called after each
    asset (in completion order); the returned list is in input order. ``baseline`` (see
    :mod:`renderer.baseline`) marks accepted known differences.

    Each subprocess sets its device up before it takes its first model (a warm-up the ``-j``
    workers do side by side), so no model's time carries it; ``stats["setup"]`` (when ``stats``
    is given) lists each worker's set-up seconds.
    """
    from .baseline import apply_baseline  # noqa: PLC0415

    options = options or ValidateOptions()
    paths = [Path(p) for p in paths]
    out: list[ValidationResult | None] = [None] * len(paths)

    def done(i: int, r: ValidationResult) -> None:
        if baseline:
            apply_baseline(r, baseline)
        out[i] = r
        if progress:
            progress(r)

    if not isolate:
        for i, p in enumerate(paths):
            done(i, validate_model(p, options, isolate=False))
        return [r for r in out if r is not None]
    jobs = max(1, min(int(jobs), len(paths) or 1))
    setups: list[float] = []
    if stats is not None:
        stats["setup"] = setups

    def warm(pool: WorkerPool) -> None:
        if paths:
            s = pool.warm()
            if s is not None:
                setups.append(s)

    if jobs == 1:
        with WorkerPool(options) as pool:
            warm(pool)
            for i, p in enumerate(paths):
                done(i, pool.validate(p))
        return [r for r in out if r is not None]
    import queue  # noqa: PLC0415
    import threading  # noqa: PLC0415

    todo: "queue.Queue[int]" = queue.Queue()
    for i in range(len(paths)):
        todo.put(i)
    lock = threading.Lock()

    def worker() -> None:
        with WorkerPool(options) as pool:  # subprocess I/O releases the GIL: threads suffice
            warm(pool)
            while True:
                try:
                    i = todo.get_nowait()
                except queue.Empty:
                    return
                r = pool.validate(paths[i])
                with lock:
                    done(i, r)

    threads = [threading.Thread(target=worker, daemon=True) for _ in range(jobs)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return [r for r in out if r is not None]
