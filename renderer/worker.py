"""The renderer subprocess and the pool that drives it.

``python -m renderer.worker`` sets up Vulkan once, then answers one JSON request per line on
stdin (``{"model": path, "options": {...}}``) with one JSON line (``{"result": {...}}``) on a
private copy of its stdout; the real fd 1 is pointed at stderr so nothing the driver or the
validation layer prints can corrupt the protocol.

:class:`WorkerPool` starts the subprocess with lavapipe's environment, enforces a timeout
per asset, and restarts the subprocess after a crash or a timeout, so one bad asset fails
alone and the batch goes on.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, BinaryIO

from assetpipe.core.errors import RenderError

from ._vk import renderer_env
from .results import ValidateOptions, ValidationResult

READY_TIMEOUT_S = 60.0


def _test_hooks(model: str) -> None:
    """Fault injection for the tests: die or hang on a model whose name matches.

    ``ASSETPIPE_RENDERER_CRASH_ON=<file name>`` kills the process with SIGKILL (a driver
    crash), ``ASSETPIPE_RENDERER_HANG_ON=<file name>`` sleeps forever (a driver hang).
    """
    name = Path(model).name
    if name and os.environ.get("ASSETPIPE_RENDERER_CRASH_ON") == name:
        os.kill(os.getpid(), signal.SIGKILL)
    if name and os.environ.get("ASSETPIPE_RENDERER_HANG_ON") == name:
        time.sleep(3600)


def _serve() -> int:
    """The worker's main loop (runs in the subprocess)."""
    proto = os.fdopen(os.dup(1), "w", buffering=1, encoding="utf-8")
    os.dup2(2, 1)  # stray prints from C code go to stderr
    sys.stdout = sys.stderr
    from .session import shared_renderer  # noqa: PLC0415
    from .validate import run_checks  # noqa: PLC0415

    renderer = None
    setup = 0.0
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        req = json.loads(line)
        if req.get("cmd") == "quit":
            break
        opts = ValidateOptions.from_dict(req.get("options", {}))
        try:
            if renderer is None:
                t0 = time.perf_counter()
                renderer = shared_renderer(opts.width, opts.height, validation=opts.validation_layer,
                                           shader_cache=Path(opts.shader_cache) if opts.shader_cache else None)
                import PIL.Image  # noqa: F401,PLC0415 - warm imports are part of set-up
                import trimesh  # noqa: F401,PLC0415
                from .cull import warm  # noqa: PLC0415 - the culling kernel (numba), loaded once
                from .ref_mips import warm as warm_mips  # noqa: PLC0415 - the reference's mip kernels

                warm()
                warm_mips()
                setup = time.perf_counter() - t0
                proto.write(json.dumps({"ready": True, "setup": setup}) + "\n")
            if req.get("cmd") == "ping":  # a warm-up: the set-up is reported here, charged to no asset
                proto.write(json.dumps({"pong": True, "setup": setup}) + "\n")
                setup = 0.0
                continue
            _test_hooks(req["model"])
            result = run_checks(Path(req["model"]), opts, renderer)
            result.timings["setup"] = setup
            setup = 0.0  # charged to the first asset of this process only
            proto.write(json.dumps({"result": result.to_json()}) + "\n")
        except RenderError as exc:
            proto.write(json.dumps({"error": str(exc)}) + "\n")
        except Exception as exc:  # noqa: BLE001 - report, keep serving
            proto.write(json.dumps({"error": f"internal error: {type(exc).__name__}: {exc}",
                                    "traceback": traceback.format_exc()}) + "\n")
    return 0


class WorkerPool:
    """One long-lived renderer subprocess, restarted after a crash or timeout."""

    def __init__(self, options: ValidateOptions | None = None) -> None:
        self.options = options or ValidateOptions()
        self.proc: subprocess.Popen[bytes] | None = None
        self._stderr: BinaryIO | None = None
        self._buf = b""
        self.restarts = 0
        self.setup_seconds = 0.0  # device set-up measured by warm()
        self._ready = False  # the running process has set its device up

    # ------------------------------------------------------------------ process control
    def _start(self) -> None:
        if self._stderr is not None:
            self._stderr.close()
        self._stderr = tempfile.TemporaryFile()
        env = renderer_env()
        root = str(Path(__file__).resolve().parents[1])
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        self.proc = subprocess.Popen([sys.executable, "-m", "assetpipe.renderer.worker"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self._stderr, env=env, cwd=os.getcwd())
        self._buf = b""
        self._ready = False

    def _stop(self, kill: bool = False) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        try:
            if not kill and proc.poll() is None and proc.stdin:
                proc.stdin.write(b'{"cmd": "quit"}\n')
                proc.stdin.flush()
                proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            pass
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for f in (proc.stdin, proc.stdout):
            if f:
                f.close()

    def _stderr_tail(self, limit: int = 1500) -> str:
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        data = self._stderr.read().decode("utf-8", "replace").strip()
        return data[-limit:]

    def _readline(self, deadline: float) -> dict[str, Any] | None:
        """The next JSON line, or None on EOF/timeout (check ``proc.poll()``)."""
        assert self.proc is not None and self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        sel = selectors.DefaultSelector()
        sel.register(fd, selectors.EVENT_READ)
        try:
            while b"\n" not in self._buf:
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(timeout=left):
                    return None
                chunk = os.read(fd, 1 << 16)
                if not chunk:  # EOF: the process is gone; reap it so poll() tells how
                    try:
                        self.proc.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        pass
                    return None
                self._buf += chunk
        finally:
            sel.close()
        line, self._buf = self._buf.split(b"\n", 1)
        return json.loads(line)

    def _send(self, msg: dict[str, Any]) -> bool:
        try:
            assert self.proc is not None and self.proc.stdin is not None
            self.proc.stdin.write((json.dumps(msg) + "\n").encode())
            self.proc.stdin.flush()
            return True
        except (OSError, ValueError):
            return False

    def _death(self) -> str:
        assert self.proc is not None
        rc = self.proc.poll()
        if rc is None:
            return "did not answer"
        if rc < 0:
            try:
                name = signal.Signals(-rc).name
            except ValueError:
                name = str(-rc)
            return f"died with signal {name} (driver crash?)"
        return f"exited with status {rc}"

    # ---------------------------------------------------------------------------- API
    def warm(self) -> float | None:
        """Start the subprocess and set its device up before the first asset (``-j`` workers do
        this side by side); returns the set-up seconds, or None if the process did not answer
        (the first :meth:`validate` then restarts it and reports why)."""
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        if not self._send({"cmd": "ping", "options": self.options.to_dict()}):
            return None
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            msg = self._readline(deadline)
            if msg is None:
                return None
            if msg.get("pong"):
                self._ready = True
                self.setup_seconds = float(msg.get("setup", 0.0))
                return self.setup_seconds

    def validate(self, model_json: Path | str) -> ValidationResult:
        """Validate one model in the subprocess; failures of the process fail this model only."""
        model_json = Path(model_json)
        t0 = time.monotonic()
        if self.proc is None or self.proc.poll() is not None:
            if self.proc is not None:
                self._stop(kill=True)
                self.restarts += 1
            self._start()
        timeout = float(self.options.timeout_s)
        fail = ValidationResult(model=str(model_json), id=model_json.name[: -len(".json")]
                                if model_json.name.endswith(".json") else model_json.stem)
        if not self._send({"model": str(model_json.resolve()), "options": self.options.to_dict()}):
            fail.error = f"renderer process {self._death()}: {self._stderr_tail()}"
            self._stop(kill=True)
            return fail
        deadline = t0 + timeout + (0.0 if self._ready else READY_TIMEOUT_S)  # a warm process is set up
        while True:
            msg = self._readline(deadline)
            if msg is None:
                if self.proc.poll() is None:
                    fail.error = f"timed out after {timeout:.0f} s; the renderer process was killed"
                else:
                    tail = self._stderr_tail()
                    fail.error = f"renderer process {self._death()} while validating this asset" + (
                        f"; its last output: {tail}" if tail else "")
                self._stop(kill=True)
                self.restarts += 1
                return fail
            if msg.get("ready"):
                self._ready = True
                deadline = time.monotonic() + timeout  # the timeout counts from device set-up
                continue
            if "result" in msg:
                return ValidationResult.from_json(msg["result"])
            fail.error = msg.get("error", "unknown renderer error")
            return fail

    def close(self) -> None:
        self._stop()
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None

    def __enter__(self) -> "WorkerPool":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


if __name__ == "__main__":
    sys.exit(_serve())
