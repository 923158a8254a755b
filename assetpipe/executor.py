"""The executor seam: where the build graph's ready steps run.

The graph hands each phase's missing steps to an executor as task calls
``(task, store_root, *plain args)`` and gets ``(status, value, seconds)`` back in call order.
Two executors exist:

* :class:`assetpipe.graph.Executor`: inline, or a local process pool (``-j N``); tasks read
  and write the local cache folder directly;
* :class:`DaskExecutor`: a Dask ``distributed`` cluster (``--scheduler tcp://HOST:PORT``, or
  ``run_build(..., scheduler=...)``). Workers never see the client's cache or output folder:

  - the blobs a step reads (its blob arguments, :func:`input_blobs`) travel with the task,
    by content;
  - the worker runs the task against a private scratch store, verifies nothing leaked in, and
    returns the record with the bytes of every blob it names;
  - the client checks each returned blob against its digest and writes it, and the record,
    to its own store (and so to the shared remote tier, when there is one).

  Source files (the model files, their .bin/.mtl, image files) are read by the workers at
  their absolute path on the client: every worker must see the source tree at the same path
  (a shared filesystem, or the same checkout). A worker whose assetpipe, step versions or
  library versions differ from the client's refuses the step (its output would be stored
  under the client's key), so a mixed farm fails loudly instead of poisoning the cache.

ETC2/EAC blocks also depend on the etcpak build that encodes them (its SIMD variant, chosen by
CPU), so an ETC2 texture step's key names that build (:func:`machine_libs`). The key is made
on the client, with the client's build; the worker encodes with **the build the key names**
(``texture_compress.use_etcpak_build``: an AVX-512 worker runs the AVX2 build for a client on an
AVX2 CPU), so the bytes are those a local build on the client makes. A worker whose CPU cannot
run that build cannot make those bytes: before a phase with ETC2 steps the client asks every
worker which builds it runs and stops the build with one line naming the worker and the build
to key by instead (``ASSETPIPE_ETCPAK_BUILD`` on the client); a worker that joins later and
gets such a step refuses it, and the build stops with the same kind of line.

Dask's nanny starts worker processes with ``MALLOC_TRIM_THRESHOLD_=65536``
(``distributed.nanny.pre-spawn-environ``). Setting it turns off glibc's adaptive mmap threshold:
every array above 128 KiB is then a fresh mmap, zero-filled page by page and unmapped when
freed. The LOD step (many short-lived arrays of a few MB) took 10x the page faults and 1.6x
the CPU time that way. :func:`step_malloc` gives a worker back the allocator settings a local
build process runs with (docs/FARM.md, "The seam's overhead: where the time went").

A worker killed mid-step is Dask's business: the scheduler reschedules its tasks on the
others (``distributed.scheduler.allowed-failures``, default 3); the steps are pure, so the
outputs are byte-identical to a local build.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import uuid
from pathlib import Path

from assetpipe import steps
from assetpipe.core.errors import AssetpipeError
from assetpipe.core.hashing import PREFIX, digest_bytes, digest_json

CONNECT_TIMEOUT = 10.0  # seconds to reach the scheduler before giving up with one clear error


class SchedulerError(AssetpipeError):
    """The Dask scheduler cannot be reached (or was lost during the build)."""


class WorkerBuildError(SchedulerError):
    """A worker cannot run the library build a step's key names (ETC2: the etcpak build)."""


_fingerprint: str | None = None


def environment_fingerprint() -> str:
    """What a step's output depends on besides its inputs: assetpipe's version, the step
    versions and the library versions (the last two are part of every key)."""
    global _fingerprint
    if _fingerprint is None:
        from assetpipe import __version__, versions

        _fingerprint = digest_json({"assetpipe": __version__, "steps": versions.STEP_VERSIONS,
                                    "libs": versions.library_versions()})
    return _fingerprint


def blob_digests(value) -> list[str]:
    """Every ``xxh3:`` digest among a task's arguments (nested lists, tuples, dicts)."""
    out: list[str] = []
    if isinstance(value, str):
        if value.startswith(PREFIX):
            out.append(value)
    elif isinstance(value, dict):
        for v in value.values():
            out.extend(blob_digests(v))
    elif isinstance(value, (list, tuple)):
        for v in value:
            out.extend(blob_digests(v))
    return out


def input_blobs(fn, args: list) -> list[str]:
    """The blobs a task reads (by digest): for the build's tasks, exactly their blob
    arguments (the source digests an encode step lists are not sent); for any other task,
    every digest among its arguments."""
    if fn is steps.task_import:
        return []
    if fn in (steps.task_mesh, steps.task_lod, steps.task_encode):
        return [args[1] if fn is steps.task_encode else args[0]]
    if fn is steps.task_lod_handmade:
        return list(args[0])
    if fn in (steps.task_texture, steps.task_texture_uses):
        return [args[0]["digest"]] if args[0].get("path") is None else []
    return blob_digests(args)


def machine_libs(fn, args: list) -> dict:
    """The parts of a task's key that depend on the machine's build of a library rather than its
    version (``{}`` for most tasks): for an ETC2 texture step ``{"etcpak-build": NAME}``, made
    by the same function as the key (``steps.texture_key_libs``), so they cannot disagree."""
    if fn in (steps.task_texture, steps.task_texture_uses):
        return steps.texture_key_libs({}, args[-1])
    return {}


def etcpak_builds_here() -> list[str]:
    """On a worker (``client.run``): the etcpak builds this process can encode ETC2/EAC with."""
    from assetpipe.pipelines.texture_compress import etcpak_builds

    return list(etcpak_builds())


def _cannot_run(machine: dict) -> str | None:
    """Why this process cannot make the bytes ``machine`` names (None: it can)."""
    build = machine.get("etcpak-build")
    if build is None:
        return None
    from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV, etcpak_builds

    here = etcpak_builds()
    if build in here:
        return None
    return (f"worker {os.uname().nodename} pid {os.getpid()} cannot run etcpak build {build}, which the ETC2 "
            f"texture keys name (it runs {', '.join(here)}; their blocks differ): set {ETCPAK_BUILD_ENV}="
            f"{here[0]} on the client so that the keys name a build every worker runs, or leave this worker out")


def _absolute(fn, args: list) -> list:
    """Source paths made absolute (a worker's working folder is not the client's)."""
    args = list(args)
    if fn is steps.task_import:
        args[0] = os.path.abspath(args[0])
    elif fn in (steps.task_texture, steps.task_texture_uses):
        args[1] = os.path.abspath(args[1])
    return args


# glibc's mallopt parameters (<malloc.h>) and the values step_malloc sets
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
# the ceiling of glibc's adaptive mmap threshold on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX): in a
# local build process the threshold rises to the largest array freed so far, up to this ...
STEP_MMAP_THRESHOLD = 32 * 2**20
# ... and its trim threshold, which glibc keeps at twice the mmap threshold as it adapts
STEP_TRIM_THRESHOLD = 2 * STEP_MMAP_THRESHOLD
_malloc_done: str | None = None


def step_malloc() -> str:
    """In a worker process: undo a fixed ``MALLOC_*_`` setting from the environment (Dask's
    ``MALLOC_TRIM_THRESHOLD_=65536``), once. glibc cannot switch its adaptive thresholds back
    on, so this sets the ceiling they rise toward in a local build process. Returns what it did."""
    global _malloc_done
    if _malloc_done is not None:
        return _malloc_done
    fixed = sorted(k for k in os.environ if k.startswith("MALLOC_") and k.endswith("_THRESHOLD_"))
    if not fixed:
        _malloc_done = "glibc defaults (adaptive)"
        return _malloc_done
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        ok = libc.mallopt(M_MMAP_THRESHOLD, STEP_MMAP_THRESHOLD) == 1 and \
            libc.mallopt(M_TRIM_THRESHOLD, STEP_TRIM_THRESHOLD) == 1
    except (OSError, AttributeError):  # not glibc: its allocator does not read MALLOC_*_ either
        ok = False
    _malloc_done = (f"{', '.join(fixed)} in the environment; mmap threshold {STEP_MMAP_THRESHOLD >> 20} MiB, "
                    f"trim threshold {STEP_TRIM_THRESHOLD >> 20} MiB" if ok else
                    f"{', '.join(fixed)} in the environment; left as is (no glibc mallopt)")
    return _malloc_done


def run_on_worker(fn, args: list, inputs: dict[str, bytes], fingerprint: str, machine: dict | None = None):
    """On a worker: run one task against a scratch store holding ``inputs``, with the library
    builds ``machine`` names (:func:`machine_libs`; status ``"refused"`` when this worker cannot
    run them).

    Returns (status, value, seconds, {digest: bytes} of the blobs the record names)."""
    import contextlib

    from assetpipe.cache.store import Store

    step_malloc()
    mine = environment_fingerprint()
    if mine != fingerprint:
        return ("internal", f"worker {os.uname().nodename} pid {os.getpid()} runs a different assetpipe or "
                f"library versions than the client (environment {mine} != {fingerprint}); install the same "
                "versions on every worker", 0.0, {})
    machine = machine or {}
    why = _cannot_run(machine)
    if why is not None:
        return "refused", why, 0.0, {}
    root = tempfile.mkdtemp(prefix="assetpipe-step-")
    try:
        store = Store(Path(root))
        for digest, data in inputs.items():
            if store.put_blob(data) != digest:
                return "internal", f"input blob {digest} arrived damaged", 0.0, {}
        with contextlib.ExitStack() as stack:
            if "etcpak-build" in machine:  # encode with the build the key names, not this CPU's best
                from assetpipe.pipelines.texture_compress import use_etcpak_build

                stack.enter_context(use_etcpak_build(machine["etcpak-build"]))
            status, value, secs = steps.call_task(fn, root, *args)
        blobs: dict[str, bytes] = {}
        if status == "ok":
            for digest in value["blobs"].values():
                data = store.get_blob(digest)
                if data is None:
                    return "internal", f"{fn.__name__} named blob {digest} but did not write it", secs, {}
                blobs[digest] = data
        return status, value, secs, blobs
    finally:
        shutil.rmtree(root, ignore_errors=True)


class DaskExecutor:
    """Runs task calls on a Dask cluster; results in call order (see the module docstring).

    ``scheduler``: an address (``tcp://HOST:PORT``), a ``distributed.Client``, or a cluster
    object (``LocalCluster``). The connection is made at the first step to run, so a build
    with nothing to do never contacts the scheduler. ``store`` is the client's store (set by
    :func:`assetpipe.build.run_build`)."""

    def __init__(self, scheduler, store=None, timeout: float = CONNECT_TIMEOUT):
        self.scheduler = scheduler
        self.store = store
        self.timeout = timeout
        self.client = None
        self._own_client = False
        # bytes sent with tasks (inputs) and returned (outputs), tasks run, and the client's own
        # seconds (reading inputs and submitting; fetching, checking and storing results)
        self.moved = {"to_workers": 0, "from_workers": 0, "tasks": 0, "client_s": 0.0}
        self.per_step: dict[str, dict] = {}  # task name -> {"tasks", "to_workers", "from_workers", "seconds"}
        self.worker_builds: dict[str, list[str]] = {}  # worker address -> etcpak builds it runs (asked once)

    def _connect(self):
        if self.client is not None:
            return self.client
        from distributed import Client

        if isinstance(self.scheduler, Client):
            self.client = self.scheduler
            return self.client
        where = self.scheduler if isinstance(self.scheduler, str) else getattr(self.scheduler, "scheduler_address",
                                                                               repr(self.scheduler))
        try:
            self.client = Client(self.scheduler, timeout=self.timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise SchedulerError(f"cannot reach the Dask scheduler at {where} within {self.timeout:g} s "
                                 f"({type(exc).__name__}); is `dask scheduler` running there?") from None
        self._own_client = True
        return self.client

    def map(self, calls: list[tuple]) -> list[tuple[str, object, float]]:
        """Submit the calls with their input blobs, at most ``window`` in flight (so the
        client never holds a whole phase's inputs at once), refilled as results arrive."""
        if not calls:
            return []
        import warnings

        from distributed import as_completed
        from distributed.comm.core import CommClosedError

        client = self._connect()
        fp = environment_fingerprint()
        machines = [machine_libs(fn, args) for fn, _root, *args in calls]
        self._check_worker_builds(client, {m["etcpak-build"] for m in machines if "etcpak-build" in m})
        workers = len(client.scheduler_info().get("workers", {})) or 8
        window = max(16, 4 * workers)
        results: list = [None] * len(calls)
        pending = iter(enumerate(calls))
        running: dict = {}
        done = as_completed(loop=client.loop)

        def submit_next() -> bool:
            try:
                i, (fn, _root, *args) = next(pending)
            except StopIteration:
                return False
            t0 = time.perf_counter()
            machine = machines[i]
            args = _absolute(fn, args)
            inputs = {}
            for d in dict.fromkeys(input_blobs(fn, args)):
                data = self.store.get_blob(d) if self.store.has_blob(d) else None
                if data is not None:
                    inputs[d] = data
            with warnings.catch_warnings():  # "large graph": the inputs travel with the task on purpose
                warnings.simplefilter("ignore", UserWarning)
                f = client.submit(run_on_worker, fn, args, inputs, fp, machine or None, pure=False,
                                  key=f"{fn.__name__}-{uuid.uuid4().hex}")
            running[f.key] = (i, fn, sum(len(b) for b in inputs.values()))
            done.add(f)
            self.moved["client_s"] += time.perf_counter() - t0
            return True

        for _ in range(window):
            if not submit_next():
                break
        for f in done:
            t0 = time.perf_counter()
            i, fn, size = running.pop(f.key)
            try:
                status, value, secs, blobs = f.result()
            except (OSError, CommClosedError) as exc:
                raise SchedulerError(f"lost the Dask scheduler during the build ({type(exc).__name__}: {exc}); "
                                     "steps finished so far are cached") from None
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the step crashed every worker it met
                status, value, secs, blobs = "internal", f"{type(exc).__name__} on the Dask cluster: {exc}", 0.0, {}
            f.release()
            if status == "refused":  # a worker that joined after _check_worker_builds: no bytes of another build
                raise WorkerBuildError(str(value))
            back = 0
            for digest, data in blobs.items():
                back += len(data)
                if digest_bytes(data) != digest:
                    status, value = "internal", f"a worker returned blob {digest} damaged"
                    break
                self.store.put_blob(data)
            self.moved["to_workers"] += size
            self.moved["from_workers"] += back
            self.moved["tasks"] += 1
            st = self.per_step.setdefault(fn.__name__, {"tasks": 0, "to_workers": 0, "from_workers": 0,
                                                         "seconds": 0.0})
            st["tasks"] += 1
            st["to_workers"] += size
            st["from_workers"] += back
            st["seconds"] += secs
            results[i] = (status, value, secs)
            self.moved["client_s"] += time.perf_counter() - t0
            submit_next()
        return results

    def _check_worker_builds(self, client, wanted: set[str]) -> None:
        """Before ETC2 steps run: every worker must run the etcpak build(s) their keys name
        (else its blocks would not be the ones the key describes). Asked once per worker."""
        if not wanted:
            return
        from assetpipe.pipelines.texture_compress import ETCPAK_BUILD_ENV, ETCPAK_BUILD_ORDER, etcpak_builds

        workers = set(client.scheduler_info().get("workers", {}))
        if not workers <= set(self.worker_builds):
            self.worker_builds.update(client.run(etcpak_builds_here))
        for addr in sorted(workers):
            runs = self.worker_builds.get(addr)
            missing = sorted(wanted - set(runs or wanted))
            if missing:
                common = set(etcpak_builds()).intersection(*(self.worker_builds.get(a, ["none"]) for a in workers))
                best = min(common, key=ETCPAK_BUILD_ORDER.index) if common else "none"
                raise WorkerBuildError(
                    f"worker {addr} cannot run etcpak build {', '.join(missing)}, which this build's ETC2 texture "
                    f"keys name (this machine's; the worker runs {', '.join(runs)}; their blocks differ): set "
                    f"{ETCPAK_BUILD_ENV}={best} here so that the keys name a build every worker runs, or leave that "
                    "worker out")

    def close(self):
        if self._own_client and self.client is not None:
            self.client.close()
            self.client = None
            self._own_client = False


def make_executor(scheduler, store):
    """The executor for ``run_build(scheduler=...)``: a :class:`DaskExecutor` given as is (the
    caller owns it and reads its counters), else one made for this build."""
    if isinstance(scheduler, DaskExecutor):
        scheduler.store = store
        return _Borrowed(scheduler)
    return DaskExecutor(scheduler, store)


class _Borrowed:
    """A caller's executor: used, not closed, by the graph."""

    def __init__(self, inner: DaskExecutor):
        self.inner = inner

    def map(self, calls):
        return self.inner.map(calls)

    def close(self):
        pass
