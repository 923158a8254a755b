"""The build graph: steps keyed by what they read, looked up in the store, run when missing.

Per model the steps are::

    import ──> mesh ──> lod ──┐
       └────> texture (per image a model uses, all its uses in one) ──> encode ──> materialise

A step's cache key is the digest of: its name and version (:mod:`assetpipe.versions`), its
options in canonical JSON, the digests of everything it reads (source files, or the blobs of
the steps before it), and the versions of the libraries it depends on. Because keys use the
*output* digests of earlier steps, a source edit that changes nothing downstream (say,
whitespace in a .gltf) stops at the first step whose output is unchanged.

The import step discovers what it reads (.bin, .mtl) only by running; its record lists those
files with their digests and is valid only while they all still match (as ccache's manifests).
Images are not import dependencies: a texture edit reruns only the texture steps that read
that image and the encode steps of the models that use them.

Steps run in phases (import; mesh; lod + textures + encode), each phase's missing steps in
parallel on a process pool when ``jobs > 1``. In the last phase a model's encode step starts as
soon as its own chain and textures are in, and the build writes that model's outputs while the
workers go on with the other models (:meth:`Graph._finish_streamed`; an executor of whole phases,
the farm's, runs lod + textures, then encode). Results do not depend on ``jobs`` or on the order
steps finish in. When an import ran, the build process loads the LOD kernels on a thread during
the mesh phase and forks new workers for the later phases: they inherit the kernels instead of
each loading them (numba's set-up, about 0.75 s a process; :meth:`Executor.warm`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from assetpipe import steps, versions
from assetpipe.core.hashing import canonical_json, digest_json
from assetpipe.cache.stat_cache import StatCache
from assetpipe.cache.store import Store

TEXTURE_DIR = "textures"


def _use_what(use: tuple, uses: list) -> str:
    """What a label says of one use (role, alpha mode, cutoff) of an image among all of a
    model's ``uses`` of it: its role, with the alpha mode (and a mask's cutoff) where another
    use has the same role, so that materials sampling one image with different alpha modes keep
    their own textures."""
    role, alpha, cutoff = use
    if sum(u[0] == role for u in uses) > 1:
        return f"{role} {alpha}" + (f" {cutoff:g}" if alpha == "MASK" else "")
    return role


def _use_label(name: str, use: tuple, uses: list) -> str:
    """The record label of one use of an image: ``texture NAME (WHAT)``."""
    return f"texture {name} ({_use_what(use, uses)})"


def _uses_label(name: str, uses: list) -> str:
    """The step label of an image's texture step: its uses joined."""
    return f"texture {name} ({', '.join(_use_what(u, uses) for u in uses)})"


@dataclass
class StepRun:
    """What happened to one step of one asset."""

    step: str
    ran: bool
    reason: str | None = None


@dataclass
class AssetState:
    """One model's way through the graph."""

    source: Path
    id: str
    error: str | None = None
    internal: str | None = None
    warnings: list[str] = field(default_factory=list)
    runs: list[StepRun] = field(default_factory=list)
    key_inputs: dict = field(default_factory=dict)  # step label -> what its key was made of
    records: dict = field(default_factory=dict)  # step label -> record
    inputs: dict = field(default_factory=dict)  # absolute path -> digest (everything read)
    texture_jobs: dict = field(default_factory=dict)  # (material, role) -> its use's record label
    texture_uses: dict = field(default_factory=dict)  # texture step label -> its uses' record labels
    outputs: dict = field(default_factory=dict)  # OUT-relative path -> blob digest
    seconds: float = 0.0  # time of the steps run for this asset (a shared step counts for each)
    options: object = None  # BuildOptions for this asset (None: the graph's)
    plan: object = None  # a scene's ModelPlan: what the scenes need of this model (None: everything)
    extra_sources: tuple = ()  # a hand-made LOD list: the files of levels 1.. (level 0 is ``source``)
    skipped: list[str] = field(default_factory=list)  # what was not built, and why
    key: str = ""  # its entry in the output state (and in explain.json)

    @property
    def level_sources(self) -> list[tuple[str, Path]]:
        """(step label suffix, file) per level file: ("", LOD0), (" L1", ...), ..."""
        return [("", self.source)] + [(f" L{k}", p) for k, p in enumerate(self.extra_sources, start=1)]

    @property
    def failed(self) -> bool:
        return self.error is not None


def explain(prev: dict | None, now: dict, hit_missing: bool = True) -> str:
    """Why a step ran: the first difference between its previous and current key inputs."""
    if not prev:
        return "new"
    if prev.get("version") != now.get("version"):
        return f"step version changed ({prev.get('version')} -> {now.get('version')})"
    changed = [k for k in sorted(set(now.get("inputs", {})) | set(prev.get("inputs", {})))
               if now.get("inputs", {}).get(k) != prev.get("inputs", {}).get(k)]
    if changed:
        return "input changed: " + ", ".join(changed)
    opts_now, opts_prev = now.get("options") or {}, prev.get("options") or {}
    if not isinstance(opts_now, dict) or not isinstance(opts_prev, dict):
        if opts_now != opts_prev:
            return "options changed"
    else:
        changed = [k for k in sorted(set(opts_now) | set(opts_prev)) if opts_now.get(k) != opts_prev.get(k)]
        if changed:
            return "option changed: " + ", ".join(changed)
    if prev.get("libs") != now.get("libs"):
        libs = [k for k in sorted(now.get("libs", {})) if now["libs"].get(k) != prev.get("libs", {}).get(k)]
        return "library version changed: " + ", ".join(libs)
    return "not in the cache (evicted, corrupt, or built elsewhere)"


def _with_deps(kin: dict, record: dict) -> dict:
    """Import key inputs plus the files the import discovered it read (for explanations)."""
    deps = {d["path"]: d["digest"] for d in record["meta"].get("deps", [])}
    return {**kin, "inputs": {**kin["inputs"], **deps}}


class Executor:
    """Runs task calls inline (jobs == 1) or on a process pool; results in call order."""

    def __init__(self, jobs: int):
        self.jobs = max(1, int(jobs))
        self.pool = None
        self._spare = None  # the pool's count of cores no task needs (_new_pool)
        self._warming = None
        from assetpipe.worker_life import keep_freed_memory

        keep_freed_memory()  # before the workers fork: they inherit it
        if self.jobs > 1:  # multiprocessing costs ~15 ms to import: only when asked for
            self.pool = self._new_pool()

    def warm(self) -> None:
        """Start loading the LOD kernels in this process, on a thread (the workers are busy
        with the mesh phase meanwhile): workers forked after :meth:`fresh_pool` inherit them
        instead of each loading its own, about 0.75 s a process (assetpipe/worker_life.py)."""
        if self.pool is None or self._warming is not None:
            return
        import threading

        from assetpipe.worker_life import warm_lod_kernels

        def run():
            try:
                warm_lod_kernels()
            except Exception:  # only a head start: the workers load what is missing
                pass

        self._warming = threading.Thread(target=run, name="assetpipe-warm", daemon=True)
        self._warming.start()

    def fresh_pool(self) -> None:
        """After :meth:`warm`: new workers, forked once the warming thread is done (no thread
        but the main one runs here at the fork)."""
        if self._warming is None:
            return
        self._warming.join()
        self._warming = None
        self.pool.shutdown(wait=True)
        self.pool = self._new_pool()

    def map(self, calls: list[tuple]) -> list[tuple[str, object, float]]:
        if self.pool is None or len(calls) <= 1:
            return [steps.call_task(fn, *args) for fn, *args in calls]
        out = [self.outcome(f) for f in [self.submit(call) for call in calls]]
        # the steps lost with a crashed worker's pool, each run again alone: only a step that
        # kills a worker by itself fails
        return [self.alone(call) if r[0] == CRASHED else r for call, r in zip(calls, out)]

    def submit(self, call: tuple):
        """Start one task call; a future of its ``(status, value, seconds)`` (see :meth:`outcome`).
        Inline (``jobs == 1``) it runs here, now."""
        from concurrent.futures import Future

        if self.pool is None:
            f = Future()
            f.set_result(steps.call_task(*call))
            return f
        spare = self._spare
        spare.task_started()
        f = self.pool.submit(steps.call_task, *call)
        f.add_done_callback(spare.task_ended)
        f.assetpipe_pool = self.pool
        return f

    def outcome(self, future) -> tuple[str, object, float]:
        """A finished future's ``(status, value, seconds)``. A worker that died (killed, or a
        native library's fault) takes down the pool and every task in it: those come back with
        status :data:`CRASHED`, to be run again with :meth:`alone`, and the pool is started again
        (once per broken pool)."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            return future.result()
        except BrokenProcessPool:
            if getattr(future, "assetpipe_pool", None) is self.pool:
                self._restart()
            return (CRASHED, "", 0.0)

    def alone(self, call: tuple) -> tuple[str, object, float]:
        """Run a task lost with a crashed pool again, with nothing else in the pool (the caller
        hands out nothing meanwhile): a crash now is its own, and it fails with one line. The
        line says how the worker died: killed (SIGKILL, what the system's out-of-memory killer
        sends: status ``"memory"``, not a bug of ours) or another signal (a native library's
        fault: ``"internal"``)."""
        future = self.submit(call)
        workers = self._workers()
        status, value, secs = self.outcome(future)
        if status == CRASHED:
            return _crash_outcome(_death_signal(workers), secs)
        return status, value, secs

    def _workers(self) -> list:
        """The pool's worker processes now (``multiprocessing.Process``; ProcessPoolExecutor
        keeps them in its ``_processes``; none known if that ever changes: the crash is then
        reported without its signal)."""
        procs = getattr(self.pool, "_processes", None)
        return list(procs.values()) if isinstance(procs, dict) else []

    def _new_pool(self):
        """A process pool whose workers die with this process (assetpipe/worker_life.py) and
        count the cores no task needs (:class:`assetpipe.core.cores.SpareCores`: a task handed
        to the pool takes one until it ends; an LOD step's helper threads use only the rest). A
        new count with each pool: the cores a crashed pool's tasks held are not missed."""
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        from assetpipe.core.cores import SpareCores
        from assetpipe.worker_life import init_worker

        ctx = multiprocessing.get_context()
        self._spare = SpareCores(ctx, self.jobs)
        return ProcessPoolExecutor(self.jobs, mp_context=ctx, initializer=init_worker,
                                   initargs=(os.getpid(), self._spare.value))

    def _restart(self):
        try:
            self.pool.shutdown(wait=False, cancel_futures=True)
        except Exception:
            pass
        self.pool = self._new_pool()

    def close(self):
        if self.pool is not None:
            self.pool.shutdown(wait=True)


# Rough CPU seconds of a step, only to hand the longest steps of a phase to the workers first
# (results never depend on the order): a LOD chain measured about 40 us a triangle on the
# bunny and beast (2CylinderEngine, many small parts, about 85), a texture about 2 us a byte
# of its encoded image (the corpus's largest JPEG and PNG files).
LOD_SECONDS_PER_TRIANGLE = 4e-5
TEXTURE_SECONDS_PER_BYTE = 2e-6
EMBEDDED_IMAGE_BYTES = 250_000  # an embedded image's size is not looked up: a typical one
#: the status :meth:`Executor.outcome` gives a task lost with a crashed worker's pool (never stored:
#: the task is run again alone)
CRASHED = "crashed"
ENCODE_SECONDS = 0.01  # an encode step, as estimated for handing out (most take 1-30 ms)
# The streamed last phase (Graph._finish_streamed) keeps handing out tasks while those handed out
# hold less than this much estimated work a worker, at most STREAM_MAX_QUEUED of them. With one
# task queued at a time, 1,000 one-triangle-pair models built in 16.2 s against 13.5 s for the
# phased build (the workers waited for this process to hand out each ~5 ms step)
STREAM_QUEUED_SECONDS = 0.2
STREAM_MAX_QUEUED = 64


def _death_signal(workers: list, timeout: float = 10.0) -> int | None:
    """The signal that killed one of ``workers`` (a broken pool's processes) other than the
    SIGTERM the pool sends the others when it breaks, or None (none found, or not known).

    The pool's own thread reaps its processes too: a join here can return before that thread
    has recorded the exit code (its ``waitpid`` took the status), so each code is read again
    until it is known (the pool ends every process of a broken pool at once)."""
    import signal
    import time

    deadline = time.monotonic() + timeout
    for p in workers:
        code = None
        while True:
            try:
                p.join(max(0.0, deadline - time.monotonic()))
                code = p.exitcode
            except Exception:  # noqa: BLE001 - only to name the signal
                break
            if code is not None or time.monotonic() >= deadline:
                break
            time.sleep(0.01)
        if code is not None and code < 0 and -code != signal.SIGTERM:
            return -code
    return None


def _crash_outcome(sig: int | None, secs: float) -> tuple[str, str, float]:
    """A step whose worker died running it alone: (status, message, seconds)."""
    import signal

    if sig == signal.SIGKILL:
        return ("memory", "its worker process was killed (SIGKILL) running this step alone, most likely by "
                          "the system's out-of-memory killer: the step needed more memory than was free", secs)
    if sig is None:
        how = "killed, or a native library's fault"
    else:
        try:
            how = f"{signal.Signals(sig).name}: a native library's fault"
        except ValueError:
            how = f"signal {sig}: a native library's fault"
    return ("internal", f"a build worker process crashed running this step alone ({how})", secs)


@dataclass
class _Phase:
    """The keys of one phase (:meth:`Graph._lookup`): the records found or made (None: the step
    failed), the calls to run and their hand-out order, each key's owners (asset, step label, key
    inputs) and each asset's keys in the order of its jobs, and the outcome of each key run."""

    with_record: object = None
    results: dict = field(default_factory=dict)    # key -> record | None
    to_run: dict = field(default_factory=dict)     # key -> task call
    order: list = field(default_factory=list)      # keys to run, largest estimated cost first
    rank: dict = field(default_factory=dict)       # key -> its place in ``order``
    owners: dict = field(default_factory=dict)     # key -> [(asset, label, key inputs)]
    first: dict = field(default_factory=dict)      # key -> its place among the phase's keys
    keys_of: dict = field(default_factory=dict)    # id(asset) -> (asset, {key: None} in job order)
    outcome: dict = field(default_factory=dict)    # key -> (status, value, seconds) of a run key
    cost: dict = field(default_factory=dict)       # key -> its estimated CPU seconds (when given)

    @property
    def assets(self) -> list[AssetState]:
        return [a for a, _ in self.keys_of.values()]


class Graph:
    def __init__(self, store: Store, stat_cache: StatCache, options, previous: dict, jobs: int = 1,
                 executor=None):
        """``options``: :class:`assetpipe.options.BuildOptions`; ``previous``: the last build's
        per-source step key inputs (for explanations), from the output state; ``executor``:
        where ready steps run (anything with ``map(calls)`` and ``close()``, such as
        :class:`assetpipe.executor.DaskExecutor`); None: :class:`Executor` with ``jobs``."""
        self.store = store
        self.stat = stat_cache
        self.options = options
        self.previous = previous
        self.libs = versions.library_versions()
        self.executor = executor if executor is not None else Executor(jobs)

    def _options(self, a: AssetState):
        return a.options if a.options is not None else self.options

    def _mesh_opts(self, a: AssetState) -> dict:
        return steps.options_to_json(self._options(a).mesh)

    def _lod_opts(self, a: AssetState) -> dict | None:
        return steps.options_to_json(self._options(a).lod)

    def _layout(self, a: AssetState) -> list[str]:
        return list(self._options(a).mesh.layout)

    def _tex_opts(self, a: AssetState) -> dict:
        """Texture options; a scene caps the size at what its objects can show on screen."""
        tex = self._options(a).texture
        if a.plan is not None:
            tex = a.plan.texture_options_for(a.records["import"]["meta"].get("radius"), tex)
        return steps.options_to_json(tex)

    # -- keys ---------------------------------------------------------------------------
    def _key_inputs(self, step: str, inputs: dict, opts) -> dict:
        libs = steps.texture_key_libs(self.libs, opts) if step == "texture" else self.libs
        return {"step": step, "version": versions.STEP_VERSIONS[step], "inputs": inputs, "options": opts,
                "libs": libs}

    def _run_phase(self, jobs: list[tuple[list[AssetState], str, dict, tuple]], accept=None,
                   with_record=None, costs: list[float] | None = None) -> dict[str, dict | None]:
        """jobs: (assets, step label, key inputs, task call). Looks each key up, runs the
        missing ones (each key once), stores records. Returns key -> record (None: failed).

        ``accept(call, record)``: whether a cached record is still valid (the import step's
        discovered dependencies); ``with_record(key_inputs, record)``: the key inputs to
        remember for explanations once the record is known.

        ``costs`` (one per job): an estimate of each task's work; the tasks to run are handed to
        the executor largest first, so that a long task does not start last and hold up the
        phase on one worker (results and records do not depend on the order)."""
        ph = self._lookup(jobs, accept, with_record, costs)
        for key, out in zip(ph.order, self.executor.map([ph.to_run[k] for k in ph.order])):
            self._store_result(ph, key, *out)
        for a in ph.assets:
            self._settle(ph, a)
        return ph.results

    def _lookup(self, jobs, accept=None, with_record=None, costs=None) -> _Phase:
        """A phase's keys looked up in the store (see :meth:`_run_phase`)."""
        ph = _Phase(with_record=with_record)
        if hasattr(self.store, "prefetch"):  # a remote cache tier: fetch the phase's hits in one batch
            self.store.prefetch([digest_json(kin) for _, _, kin, _ in jobs])
        cost_of = ph.cost
        for j, (assets, label, kin, call) in enumerate(jobs):
            key = digest_json(kin)
            if costs is not None:
                cost_of[key] = max(cost_of.get(key, 0.0), costs[j])
            for a in assets:
                if key not in ph.owners:
                    ph.owners[key] = []
                    ph.first[key] = len(ph.first)
                ph.owners[key].append((a, label, kin))
                ph.keys_of.setdefault(id(a), (a, {}))[1].setdefault(key, None)
            if key in ph.results or key in ph.to_run:
                continue
            rec = self.store.get_record(key)
            if rec is not None and (accept is None or accept(call, rec)):
                ph.results[key] = rec
                self.store.hits += 1
            else:  # absent, or stale: run it and overwrite the record
                ph.to_run[key] = call
                self.store.misses += 1
        ph.order = list(ph.to_run)
        if costs is not None:
            ph.order.sort(key=lambda k: -cost_of.get(k, 0.0))  # stable: ties keep the asset order
        ph.rank = {k: i for i, k in enumerate(ph.order)}
        return ph

    def _store_result(self, ph: _Phase, key: str, status: str, value, secs: float) -> None:
        """One run key's outcome: its record stored (or None: failed), kept for :meth:`_settle`."""
        if status == "ok":
            try:  # a fresh record reads back exactly as a cached one (sorted keys): same outputs
                value = json.loads(canonical_json(value))
            except ValueError:  # NaN or infinity (a value in the file overflows): that asset fails
                status, value = "nonfinite", "a number that is not finite (NaN or infinity) reached its result"
        if status == "ok":
            self.store.put_record(key, value)
            ph.results[key] = value
        else:
            ph.results[key] = None
        ph.outcome[key] = (status, value, secs)

    def _settle(self, ph: _Phase, a: AssetState) -> None:
        """Asset ``a``'s part of a phase, once each of its keys has a result: its times, its
        failures (in the order the keys were handed out) and its step runs and records (in the
        order of its jobs). The same for ``a`` whatever order the keys finished in, or whether
        the other assets of the phase are done."""
        mine = ph.keys_of.get(id(a), (a, {}))[1]
        for key in sorted((k for k in mine if k in ph.outcome), key=ph.rank.__getitem__):
            status, value, secs = ph.outcome[key]
            for o, label, _ in ph.owners[key]:
                if o is not a:
                    continue
                a.seconds += secs
                if status == "ok":
                    continue
                if status == "memory":  # value: why, when known (a worker the out-of-memory killer ended)
                    value = f"out of memory in step {label}" + (f" ({value})" if value else "")
                if label.startswith("texture"):
                    a.warnings.append(f"{label} skipped: {value if status != 'internal' else 'internal error'}")
                    if status == "internal":
                        a.warnings.append(str(value))
                elif status == "memory":
                    a.error = f"{a.source}: {value}"
                elif status == "nonfinite":
                    a.error = f"{a.source}: step {label}: {value}"
                elif status == "asset":
                    a.error = str(value)
                else:
                    a.error = f"{a.source}: internal error in step {label} ({str(value).splitlines()[0]}); please report it"
                    a.internal = str(value)
        for key in sorted(mine, key=ph.first.__getitem__):  # the phase's order of first use
            rec = ph.results.get(key)
            for o, label, kin in ph.owners[key]:
                if o is not a:
                    continue
                if ph.with_record is not None and rec is not None:
                    kin = ph.with_record(kin, rec)
                a.key_inputs[label] = kin
                ran = key in ph.to_run
                prev = self.previous.get(a.key, {}).get(label)
                a.runs.append(StepRun(label, ran, explain(prev, kin) if ran else None))
                a.records[label] = rec

    # -- the phases ---------------------------------------------------------------------
    def build(self, assets: list[AssetState], on_done=None) -> None:
        """Run the steps of ``assets``. ``on_done(asset)``: called once per asset as soon as it is
        finished (encoded, or failed at a step), while the others go on; assets failed before
        the LOD phase are left to the caller."""
        on_done = on_done or (lambda a: None)
        try:
            self._import(assets)
            live = [a for a in assets if not a.failed]
            # something to build (an import ran): the LOD kernels load here while the mesh
            # phase runs, and the workers of the next phases are forked with them loaded
            warm = getattr(self.executor, "warm", None)
            if warm is not None and self.store.misses:
                warm()
            self._mesh(live)
            live = [a for a in live if not a.failed]
            fresh = getattr(self.executor, "fresh_pool", None)
            if fresh is not None:
                fresh()
            # textures need only the import: they run beside the LOD chains, which are most of a
            # cold build's work, so the longest chain starts first instead of after every texture
            if hasattr(self.executor, "submit"):
                self._finish_streamed(live, on_done)
            else:  # an executor of whole phases (the farm's)
                self._lod_and_textures(live)
                for a in live:
                    if a.failed:
                        on_done(a)
                live = [a for a in live if not a.failed]
                self._encode(live)
                for a in live:
                    on_done(a)
        finally:
            self.executor.close()

    def _import(self, assets: list[AssetState]) -> None:
        jobs = []
        for a in assets:
            for suffix, src in a.level_sources:
                label = "import" + suffix
                try:
                    src_digest = self.stat.digest(src)
                except FileNotFoundError:
                    a.error = f"{src}: file not found"
                    break
                a.inputs[str(src.resolve())] = src_digest
                # the name too: an OBJ's unnamed mesh is named after its file (#13: a cached import
                # of the same bytes under another name gave the other file's mesh name)
                # the input budgets are its options: a changed budget re-runs the import (#13)
                budgets = steps.options_to_json(self._options(a).budgets)
                kin = self._key_inputs("import", {"source": src_digest, "name": src.name}, budgets)
                jobs.append(([a], label, kin, (steps.task_import, str(self.store.root), str(src), budgets)))
        # a record is valid only while the files the import read (.bin, .mtl) are unchanged
        self._run_phase(jobs, accept=lambda call, rec: self._deps_match(Path(call[2]), rec), with_record=_with_deps)
        for a in assets:
            for suffix, src in a.level_sources:
                rec = a.records.get("import" + suffix)
                if rec is not None:
                    for d in rec["meta"]["deps"]:
                        a.inputs[str((src.parent / d["path"]).resolve())] = d["digest"]
            if a.extra_sources and not a.failed:
                from assetpipe.scene import check_shared_materials

                metas = [a.records["import" + suffix]["meta"] for suffix, _ in a.level_sources]
                problems = check_shared_materials(metas, [p.name for _, p in a.level_sources])
                if problems:
                    a.error = f"{a.source}: hand-made LOD list: " + "; ".join(problems)

    def _deps_match(self, source: Path, rec: dict) -> bool:
        base = source.parent
        for d in rec["meta"]["deps"]:
            try:
                if self.stat.digest(base / d["path"]) != d["digest"]:
                    return False
            except (FileNotFoundError, NotADirectoryError):
                return False
        return True

    def _uv_sets(self, a: AssetState, meta: dict) -> list[int]:
        """UV set per mesh for the uv0 slot; -1 when a scene build needs no UVs for the mesh."""
        uvs = steps.uv_sets(meta["materials"], meta["meshMaterials"])
        if a.plan is None or "uv0" not in self._layout(a):
            return uvs
        from assetpipe.scene import attribute_reasons, attributes_needed

        mats = meta["materials"]
        out, skipped = [], 0
        for uv, m in zip(uvs, meta["meshMaterials"]):
            used = [mats[m]] if 0 <= m < len(mats) else []
            needed = attributes_needed(used, self._layout(a), object_texture=a.plan.needs_uv is True)
            if "uv0" in needed:
                out.append(uv)
            else:
                out.append(-1)
                skipped += 1
        if skipped:
            why = attribute_reasons(a.plan.label, ["uv0"], [])[0]
            a.skipped.append(f"{why} in {skipped} of {len(uvs)} mesh(es): written as zeros")
        return out

    def _uv_set_warnings(self, a: AssetState, meta: dict) -> list[str]:
        """Textures sampling a UV set the vertex layout does not carry (docs/FORMAT.md: uv0 holds
        the set the base colour samples, uv1 the other of TEXCOORD_0/1): an engine drawing them
        with uv0 shows them wrong, so the build says so."""
        layout = self._layout(a)
        if "uv0" not in layout:
            return []
        out = []
        used = {m for m in meta["meshMaterials"] if 0 <= m < len(meta["materials"])}
        for mi in sorted(used):
            mat = meta["materials"][mi]
            base = int(mat["textures"].get("baseColor", {}).get("texCoord", 0))
            for role, tex in mat["textures"].items():
                tc = int(tex["texCoord"])
                if tc == base or (tc in (0, 1) and base in (0, 1) and "uv1" in layout):
                    continue
                where = ("add uv1 to --layout to carry it" if tc in (0, 1) and base in (0, 1)
                         else "no layout attribute carries it")
                out.append(f"material {mi} ({mat['name']}): its {role} texture samples TEXCOORD_{tc}, "
                           f"which the vertex layout does not carry (uv0 holds TEXCOORD_{base}); {where}")
        return out

    def _mesh(self, assets: list[AssetState]) -> None:
        jobs = []
        for a in assets:
            mesh_opts = self._mesh_opts(a)
            lod0_uvs: list[int] = []
            # every level is recentred on LOD0's bounding-box centre: one offset per model
            offset = a.records["import"]["meta"]["center"] if mesh_opts.get("recenter") else None
            for suffix, _ in a.level_sources:
                imp = a.records["import" + suffix]
                blob = imp["blobs"]["geometry"]
                if not suffix:
                    uvs = lod0_uvs = self._uv_sets(a, imp["meta"])
                    a.warnings.extend(self._uv_set_warnings(a, imp["meta"]))
                else:  # levels of a hand-made list follow LOD0's decisions (same materials)
                    uvs = steps.uv_sets(imp["meta"]["materials"], imp["meta"]["meshMaterials"])
                    if len(uvs) == len(lod0_uvs):
                        uvs = [u if u0 >= 0 else -1 for u, u0 in zip(uvs, lod0_uvs)]
                mats = imp["meta"]["materials"]
                sided = [bool(0 <= m < len(mats) and mats[m]["doubleSided"]) for m in imp["meta"]["meshMaterials"]]
                kin = self._key_inputs("mesh", {"geometry": blob, "uvSets": digest_json(uvs),
                                                "doubleSided": digest_json(sided), "offset": offset}, mesh_opts)
                jobs.append(([a], "mesh" + suffix, kin, (steps.task_mesh, str(self.store.root), blob, uvs, mesh_opts,
                                                         sided, offset)))
        # the longest mesh step first (its geometry's size as the estimate): a 1M-triangle model's
        # (0.62 s) started after two small ones held up the phase, whose end the LOD phase waits for
        self._run_phase(jobs, costs=[self._blob_size(call[2]) for _, _, _, call in jobs])
        for a in assets:
            for suffix, path in a.level_sources:
                rec = a.records.get("mesh" + suffix)
                if rec is None or a.failed:
                    continue
                a.warnings.extend(rec["meta"].get("warnings", []))
                if rec["meta"].get("triangles") == 0 and rec["meta"].get("degenerate", 0) > 0:
                    a.error = (f"{path}: every one of its {rec['meta']['degenerate']} triangles is degenerate in "
                               "float32 (zero area, a repeated vertex, or a position beyond float32's range): "
                               "nothing left to build")

    def _blob_size(self, digest: str) -> float:
        """A blob's size in bytes (0 when the store cannot say): an estimate of the work a step
        reading it does, only to order the phase's tasks."""
        try:
            return float(self.store.blob_path(digest).stat().st_size)
        except (AttributeError, OSError):
            return 0.0

    def _texture_jobs(self, assets: list[AssetState]) -> tuple[list, list[float]]:
        """The texture steps of the assets, and an estimate of the CPU seconds of each: one step
        per image a model uses, with every use (role, alpha mode, cutoff) its materials make of
        it, so that the image is read and decoded once (``steps.task_texture_uses``; a single use
        is ``steps.task_texture``, keyed as before). Each use gets its own record label
        (``texture NAME (ROLE[ ALPHA[ CUTOFF]])``), filled in by :meth:`_after_textures`."""
        jobs, costs = [], []
        for a in assets:
            imp = a.records["import"]
            images = imp["meta"]["images"]
            base = a.source.parent
            tex_opts = self._tex_opts(a)
            groups: dict[str, tuple[dict, int, list]] = {}  # image digest -> (image, bytes, uses)
            used_as: dict = {}  # (material, role) -> (image digest, use)
            for mi, mat in enumerate(imp["meta"]["materials"]):
                for role, tex in mat["textures"].items():
                    image = dict(images[tex["image"]])
                    size = EMBEDDED_IMAGE_BYTES
                    if image["path"] is not None:
                        p = base / image["path"]
                        try:
                            image["digest"] = self.stat.digest(p)
                        except FileNotFoundError:
                            a.warnings.append(f"material {mi} ({mat['name']}): image {image['path']!r} disappeared; texture skipped")
                            continue
                        a.inputs[str(p.resolve())] = image["digest"]
                        try:
                            size = p.stat().st_size
                        except OSError:
                            pass
                    alpha = mat["alphaMode"] if role == "baseColor" else "OPAQUE"
                    cutoff = mat["alphaCutoff"] if alpha == "MASK" else 0.5
                    use = (role, alpha, cutoff)
                    image, size, uses = groups.setdefault(image["digest"], (image, size, []))
                    if use not in uses:
                        uses.append(use)
                    used_as[(mi, role)] = (image["digest"], use)
            for key, (digest, use) in used_as.items():
                image, _, uses = groups[digest]
                a.texture_jobs[key] = _use_label(image["name"], use, uses)
            for digest, (image, size, uses) in groups.items():
                if len(uses) == 1:
                    role, alpha, cutoff = uses[0]
                    tin = {"image": digest, "role": role, "alphaMode": alpha, "alphaCutoff": cutoff}
                    call = (steps.task_texture, str(self.store.root), image, str(base), role, alpha, cutoff, tex_opts)
                else:
                    tin = {"image": digest, "uses": [list(u) for u in uses]}
                    call = (steps.task_texture_uses, str(self.store.root), image, str(base),
                            [list(u) for u in uses], tex_opts)
                label = _uses_label(image["name"], uses)
                a.texture_uses[label] = [_use_label(image["name"], u, uses) for u in uses]
                jobs.append(([a], label, self._key_inputs("texture", tin, tex_opts), call))
                # only to order the tasks: decoded once, and each further use filters the image
                # again (a guess, not measured: half a use's cost)
                costs.append(TEXTURE_SECONDS_PER_BYTE * size * (1.0 + 0.5 * (len(uses) - 1)))
        return jobs, costs

    @staticmethod
    def _use_records(a: AssetState) -> None:
        """Each texture use's record (``steps.task_texture``'s form) under its own label, out of
        its image's step record (the same record for a single use); none where that step failed."""
        for label, use_labels in a.texture_uses.items():
            rec = a.records.get(label)
            if len(use_labels) == 1:
                continue  # the step's own label and record
            for i, ul in enumerate(use_labels):
                a.records[ul] = None if rec is None else steps.texture_use_record(rec, i)

    def _after_textures(self, assets: list[AssetState]) -> None:
        for a in assets:
            self._use_records(a)
        for a in assets:  # textures over the build's max_size (a scene's own caps are reported below)
            if a.plan is None and not a.failed:
                for label in dict.fromkeys(a.texture_jobs.values()):
                    rec = a.records.get(label)
                    if rec is not None:
                        a.warnings.extend(rec["meta"].get("warnings", []))
        for a in assets:
            if a.plan is None or a.failed:
                continue
            cap = self._tex_opts(a).get("max_size")
            for label in dict.fromkeys(a.texture_jobs.values()):
                rec = a.records.get(label)
                if rec is None or cap is None:
                    continue
                m = rec["meta"]
                if max(m.get("sourceWidth", 0), m.get("sourceHeight", 0)) > max(m["width"], m["height"]):
                    # the scene lowered the cap, or it is the build's own maximum texture size
                    why = ("the build's maximum texture size (--max-texture-size)"
                           if cap == self._options(a).texture.max_size
                           else "the largest on-screen size or the scene's texture budget")
                    a.skipped.append(f"{a.plan.label}: {label}: mip levels above {m['width']}x{m['height']} not built "
                                     f"(source {m['sourceWidth']}x{m['sourceHeight']}; capped at {cap} px by {why})")

    def _lod_jobs(self, assets: list[AssetState]) -> tuple[list, list[float]]:
        """The LOD steps of the assets, and an estimate of the CPU seconds of each."""
        jobs = []
        for a in assets:
            lod_opts, layout = self._lod_opts(a), self._layout(a)
            if a.extra_sources:
                blobs = [a.records["mesh" + suffix]["blobs"]["mesh"] for suffix, _ in a.level_sources]
                kin = self._key_inputs("lod", {f"mesh{k}": b for k, b in enumerate(blobs)},
                                       {"lod": lod_opts, "layout": layout, "handmade": True})
                jobs.append(([a], "lod", kin, (steps.task_lod_handmade, str(self.store.root), blobs, lod_opts)))
                continue
            blob = a.records["mesh"]["blobs"]["mesh"]
            imp = a.records["import"]["meta"]  # double-sided materials keep reversed twins apart
            sided = [bool(imp["materials"][m]["doubleSided"]) if 0 <= m < len(imp["materials"]) else False
                     for m in imp["meshMaterials"]]
            groups = steps.material_groups(imp["materials"], imp["meshMaterials"])
            kin = self._key_inputs("lod", {"mesh": blob}, {"lod": lod_opts, "layout": layout, "doubleSided": sided,
                                                            "materialGroups": groups})
            # a model's meshes are measured on up to -j threads (local builds; a farm's workers
            # choose for themselves): -j 1 stays on one core
            threads = getattr(self.executor, "jobs", None)
            jobs.append(([a], "lod", kin, (steps.task_lod, str(self.store.root), blob, layout, lod_opts, sided,
                                           threads, groups)))
        # the LOD work grows with the triangles (measuring each level dominates it)
        costs = [LOD_SECONDS_PER_TRIANGLE * float((a.records.get("mesh") or {}).get("meta", {}).get("triangles", 0))
                 for assets, _, _, _ in jobs for a in assets[:1]]
        return jobs, costs

    def _lod_and_textures(self, assets: list[AssetState]) -> None:
        """One phase for the LOD chains and the textures (independent steps), handed to the
        workers longest first by their estimated cost."""
        lod_jobs, lod_costs = self._lod_jobs(assets)
        tex_jobs, tex_costs = self._texture_jobs(assets)
        self._run_phase(lod_jobs + tex_jobs, costs=lod_costs + tex_costs)
        self._after_textures(assets)

    def _kept_levels(self, a: AssetState) -> list[list[int]] | None:
        """Per mesh, the chain levels a scene can select (None: all of them)."""
        if a.plan is None:
            return None
        radius = a.records["import"]["meta"].get("radius")
        keep, reasons = [], []
        for switches in a.records["lod"]["meta"]["switchDistances"]:
            keep.append(a.plan.kept_levels(switches, radius))
            reasons.extend(a.plan.level_reasons(switches, radius))
        for r in dict.fromkeys(reasons):
            a.skipped.append(r)
        return keep

    def _materials(self, a: AssetState) -> tuple[list[dict], dict[str, str]]:
        """The encode step's material list, and the texture files (OUT path -> blob)."""
        imp = a.records["import"]["meta"]
        files: dict[str, str] = {}
        out = []
        mats = list(imp["materials"])
        for mi, mat in enumerate(mats):
            textures, texture_path = {}, ""
            transparent = mat["alphaMode"] == "BLEND"
            for role, tex in mat["textures"].items():
                label = a.texture_jobs.get((mi, role))
                rec = a.records.get(label) if label else None
                if rec is None:
                    continue
                m = rec["meta"]
                png = f"{TEXTURE_DIR}/{rec['blobs']['level0'].split(':', 1)[1][:20]}{m['level0Ext']}"
                ktx = f"{TEXTURE_DIR}/{rec['blobs']['ktx2'].split(':', 1)[1][:20]}.ktx2"
                files[png] = rec["blobs"]["level0"]
                files[ktx] = rec["blobs"]["ktx2"]
                textures[role] = {"path": png, "ktx2": ktx, "width": m["width"], "height": m["height"],
                                  "levels": m["levels"], "colorSpace": m["colorSpace"], "vkFormat": m["vkFormat"],
                                  "texCoord": tex["texCoord"], "sampler": tex["sampler"],
                                  "source": imp["images"][tex["image"]]["name"],
                                  "meanDrift": m["meanDrift"], "coverage": m["coverage"]}
                if role == "baseColor":
                    texture_path = png
                    transparent = transparent or m["hasAlphaBelow255"]
            out.append({"name": mat["name"], "baseColorFactor": mat["baseColorFactor"], "alphaMode": mat["alphaMode"],
                        "alphaCutoff": mat["alphaCutoff"], "doubleSided": mat["doubleSided"],
                        "transparent": bool(transparent), "texturePath": texture_path, "textures": textures})
        if any(not 0 <= m < len(mats) for m in imp["meshMaterials"]):
            # meshes without a material (or an invalid one) use a default one, appended last
            out.append({"name": "default", "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "alphaMode": "OPAQUE",
                        "alphaCutoff": 0.5, "doubleSided": False, "transparent": False, "texturePath": "",
                        "textures": {}})
        return out, files

    def _encode_job(self, a: AssetState) -> tuple:
        lod_blob = a.records["lod"]["blobs"]["lod"]
        materials, tex_files = self._materials(a)
        a.outputs.update(tex_files)
        sources = self._sources(a)
        warnings = list(dict.fromkeys(list(a.records["import"]["meta"]["warnings"]) + a.warnings))
        keep = self._kept_levels(a)
        layout = self._layout(a)
        tin = {"lod": lod_blob, "materials": digest_json(materials), "sources": digest_json(sources),
               "warnings": digest_json(warnings)}
        offset = a.records["import"]["meta"]["center"] if self._mesh_opts(a).get("recenter") else None
        kin = self._key_inputs("encode", tin, {"id": a.id, "layout": layout, "keep": keep, "offset": offset})
        return ([a], "encode", kin, (steps.task_encode, str(self.store.root), a.id, lod_blob, layout,
                                     materials, sources, warnings, keep, offset))

    @staticmethod
    def _after_encode(a: AssetState) -> None:
        rec = a.records.get("encode")
        if rec is not None:
            a.outputs.update(rec["blobs"])
            a.warnings = list(rec["meta"]["warnings"])

    def _encode(self, assets: list[AssetState]) -> None:
        self._run_phase([self._encode_job(a) for a in assets])
        for a in assets:
            self._after_encode(a)

    def _finish_streamed(self, assets: list[AssetState], on_done) -> None:
        """The LOD chains and textures, then each model's encode step as soon as its own chain
        and textures are in (not after every model's), and ``on_done`` for it as soon as it is
        encoded: the build process writes a model's outputs while the workers go on with the
        others' chains, instead of every model's encode and outputs waiting for the last chain.

        Inline (``jobs == 1``) each task's result is taken as soon as it has run. The pool is
        handed ``jobs + 1`` tasks at a time (one queued, so no worker waits), more
        while those hold less than :data:`STREAM_QUEUED_SECONDS` of estimated work a worker (at
        most :data:`STREAM_MAX_QUEUED`: many small models' steps, which a worker finishes faster
        than this process hands them out one by one): ready encode steps first, then what a
        model with a finished step still waits for (its textures, once its chain is in), then
        the rest largest estimated cost first. A finished model's outputs are written (``on_done``)
        after the tasks its last step freed are handed out, and while a task that finished
        meanwhile waits, it is taken first: writing a model's outputs (a copy of every texture it
        has) took up to 0.4 s of this process, while a worker that finished waited for its next
        task. Each model's records, warnings and outputs are the same as with one phase after
        the other (:meth:`_settle`), and models are written in the order they finished."""
        import heapq
        from collections import deque
        from concurrent.futures import FIRST_COMPLETED, wait

        lod_jobs, lod_costs = self._lod_jobs(assets)
        tex_jobs, tex_costs = self._texture_jobs(assets)
        ph = self._lookup(lod_jobs + tex_jobs, costs=lod_costs + tex_costs)
        waiting = {id(a): sum(k in ph.to_run for k in ph.keys_of.get(id(a), (a, {}))[1]) for a in assets}
        users: dict[str, list[AssetState]] = {}
        for k in ph.to_run:
            for a in {id(o): o for o, _, _ in ph.owners[k]}.values():
                users.setdefault(k, []).append(a)
        # the steps not handed out yet: (0 promoted / 1 not, place in ph.order, key); a promoted
        # key is pushed again and its older entry skipped when popped
        heap = [(1, ph.rank[k], k) for k in ph.order]
        handed: set[str] = set()
        encodes: deque[tuple[AssetState, _Phase]] = deque()  # ready encode steps, in order
        outputs: deque[AssetState] = deque()  # finished models whose outputs are not written yet
        running: dict = {}  # future -> (phase, key, asset whose encode step it is, or None)
        jobs = getattr(self.executor, "jobs", 1)
        queued = 0.0  # estimated seconds of the tasks handed out and not finished
        lost: list[tuple[_Phase, str, AssetState | None]] = []  # lost with a crashed pool

        def written(a: AssetState) -> None:
            """a is finished: its outputs are written now inline, else when the pool has its next
            tasks (the main loop below)."""
            if jobs <= 1:
                on_done(a)
            else:
                outputs.append(a)

        def ready(a: AssetState) -> None:
            """a's chain and textures are in: settle them, then its encode step (or done)."""
            self._settle(ph, a)
            self._after_textures([a])
            if a.failed:
                written(a)
                return
            eph = self._lookup([self._encode_job(a)])
            if not eph.order:  # cached
                self._settle(eph, a)
                self._after_encode(a)
                written(a)
            else:
                encodes.append((a, eph))

        def more() -> bool:
            """Whether to hand out another task now."""
            if lost:  # until the tasks lost with a crashed pool have run again, alone
                return False
            if not running:
                return True
            if jobs <= 1:  # inline: each result is taken as soon as it has run
                return False
            return len(running) <= jobs or (queued < STREAM_QUEUED_SECONDS * jobs
                                            and len(running) < STREAM_MAX_QUEUED)

        def finished(p: _Phase, key: str, a: AssetState | None, res: tuple) -> None:
            """A task's result: stored; an encode step's model is done, a chain's or a
            texture's models get ready or have what they still wait for go next."""
            self._store_result(p, key, *res)
            if a is not None:  # an encode step
                self._settle(p, a)
                self._after_encode(a)
                written(a)
                return
            for u in users.get(key, ()):
                waiting[id(u)] -= 1
                if waiting[id(u)] == 0:
                    ready(u)
                else:  # what u still waits for (its textures, mostly) goes next
                    for k in ph.keys_of[id(u)][1]:
                        if k in ph.to_run and k not in handed:
                            heapq.heappush(heap, (0, ph.rank[k], k))

        for a in assets:
            if waiting[id(a)] == 0:
                ready(a)
        while heap or encodes or running or lost or outputs:
            while (encodes or heap) and more():
                if encodes:
                    a, eph = encodes.popleft()
                    key = eph.order[0]
                    running[self.executor.submit(eph.to_run[key])] = (eph, key, a)
                    queued += ENCODE_SECONDS
                    continue
                _, _, key = heapq.heappop(heap)
                if key in handed:
                    continue
                handed.add(key)
                running[self.executor.submit(ph.to_run[key])] = (ph, key, None)
                queued += ph.cost.get(key, 0.0)
            if not running:
                if lost:  # the pool is empty: each lost task again, alone
                    for p, key, a in sorted(lost, key=lambda t: t[1]):
                        finished(p, key, a, self.executor.alone(p.to_run[key]))
                    lost.clear()
                elif outputs:
                    on_done(outputs.popleft())
                continue
            # a finished task first (what it frees is handed out); else one model's outputs
            done, _ = wait(running, timeout=0) if outputs else wait(running, return_when=FIRST_COMPLETED)
            if not done:
                on_done(outputs.popleft())
                continue
            for f in sorted(done, key=lambda f: running[f][1]):  # a fixed order among those done at once
                p, key, a = running.pop(f)
                queued -= ENCODE_SECONDS if a is not None else ph.cost.get(key, 0.0)
                res = self.executor.outcome(f)
                if res[0] == CRASHED:
                    lost.append((p, key, a))
                else:
                    finished(p, key, a, res)

    def _sources(self, a: AssetState) -> list[dict]:
        base = a.source.parent.resolve()
        out = []
        for path, digest in a.inputs.items():
            p = Path(path)
            try:
                rel = p.relative_to(base).as_posix()
            except ValueError:
                rel = os.path.relpath(p, base)
            out.append({"path": rel, "digest": digest})
        first = [s for s in out if s["path"] == a.source.name]
        return first + sorted((s for s in out if s["path"] != a.source.name), key=lambda s: s["path"])
