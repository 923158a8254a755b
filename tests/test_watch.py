"""``assetpipe watch``: real file edits, bounded in time (each wait gives up after TIMEOUT s)."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from assetpipe.options import DEFAULT_BUILD_OPTIONS
from assetpipe.watch import watch

REPO = Path(__file__).resolve().parents[1]
TIMEOUT = 60.0  # generous: the machine is shared; a pass takes a few seconds


@pytest.fixture
def session(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(REPO / "examples" / "pyramid", src / "pyramid")
    events: queue.Queue = queue.Queue()
    stop, ready = threading.Event(), threading.Event()
    t = threading.Thread(target=watch, args=([src], tmp_path / "out", DEFAULT_BUILD_OPTIONS),
                         kwargs=dict(jobs=1, cache_dir=tmp_path / "cache", debounce_ms=200, on_build=events.put,
                                     on_ready=lambda folders: ready.set(), stop_event=stop), daemon=True)
    t.start()
    assert ready.wait(TIMEOUT), "the watcher did not start"
    yield src, tmp_path / "out", events
    stop.set()
    t.join(TIMEOUT)
    assert not t.is_alive(), "watch did not stop"


def next_event(events: queue.Queue):
    return events.get(timeout=TIMEOUT)


def no_event(events: queue.Queue, seconds: float = 1.5) -> bool:
    try:
        events.get(timeout=seconds)
        return False
    except queue.Empty:
        return True


def edit(path: Path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new, 1))


def test_a_save_rebuilds_and_a_burst_is_one_rebuild(session):
    src, out, events = session
    first = next_event(events)
    assert first.changed == [] and first.report.counts() == {"built": 1}
    vtx = (out / "pyramid.vtx").read_bytes()
    obj = src / "pyramid" / "pyramid.obj"
    for k in range(5):  # an exporter writing the same file several times in a row
        edit(obj, "v -1 0 -1" if k == 0 else f"v -1 0 -{k}", f"v -1 0 -{k + 1}")
        time.sleep(0.02)
    ev = next_event(events)
    assert [r.status for r in ev.report.results] == ["built"] and str(obj) in ev.changed
    assert (out / "pyramid.vtx").read_bytes() != vtx
    assert no_event(events), "a burst of writes caused more than one rebuild"
    edit(src / "pyramid" / "pyramid.mtl", "Kd", "Kd ")  # whitespace only: rebuilt as needed, outputs equal
    ev = next_event(events)
    assert ev.report.failed == []


def test_a_bad_save_keeps_the_last_good_outputs_and_watching_goes_on(session):
    src, out, events = session
    next_event(events)
    good = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    obj = src / "pyramid" / "pyramid.obj"
    text = obj.read_text()
    obj.write_text("v 0 0 0\nf 1 2 3\n")  # a bad save: indices past the vertices
    ev = next_event(events)
    (bad,) = ev.report.failed
    assert str(obj) in bad.error and "\n" not in bad.error
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == good
    obj.write_text(text.replace("v 1 0 1", "v 1 0 2"))  # fixed: built again
    ev = next_event(events)
    assert ev.report.failed == [] and ev.report.counts() == {"built": 1}


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@pytest.mark.vulkan
def test_cli_watch_with_preview_until_interrupted(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(REPO / "examples" / "pyramid", src / "pyramid")
    env = {**os.environ, "PYTHONPATH": str(REPO), "ASSETPIPE_CACHE": str(tmp_path / "cache"),
           "PYTHONFAULTHANDLER": "1"}  # a hang at exit dumps every thread's stack (SIGABRT below)
    proc = subprocess.Popen([sys.executable, "-m", "assetpipe.cli", "watch", str(src), "-o", str(tmp_path / "out"),
                             "--preview", "-j", "1", "--debounce", "200"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            # Ctrl-C as a shell's foreground job gets it: a process started with
                            # SIGINT ignored or blocked keeps it so, and Python then installs no
                            # KeyboardInterrupt (the full suite hung here without this)
                            preexec_fn=_default_sigint)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()

    def wait_for(fragment: str) -> str:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            except queue.Empty:
                break
            if fragment in line:
                return line
        pytest.fail(f"no line with {fragment!r} within {TIMEOUT} s")

    try:
        assert "1 built" in wait_for("first build")
        preview = tmp_path / "out" / "pyramid-preview.png"
        wait_for("preview:")
        assert preview.is_file()
        wait_for("watching")
        before = preview.stat().st_mtime_ns
        edit(src / "pyramid" / "pyramid.obj", "v 1 0 1", "v 1 0 2")
        assert "1 built" in wait_for("change(s)")
        wait_for("preview:")
        assert preview.stat().st_mtime_ns != before
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
            time.sleep(0.5)
            rest = []
            while not lines.empty():
                rest.append(lines.get())
            pytest.fail(f"watch did not exit within {TIMEOUT} s of SIGINT; its last output:\n" + "".join(rest[-200:]))
    assert proc.returncode == 0


def test_an_unusable_output_folder_is_reported_and_watching_goes_on(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(REPO / "examples" / "pyramid", src / "pyramid")
    (tmp_path / "blocker").write_text("a file where the output folder's parent should be")
    events: queue.Queue = queue.Queue()
    stop, ready = threading.Event(), threading.Event()
    t = threading.Thread(target=watch, args=([src], tmp_path / "blocker" / "out", DEFAULT_BUILD_OPTIONS),
                         kwargs=dict(jobs=1, cache_dir=tmp_path / "cache", debounce_ms=200, on_build=events.put,
                                     on_ready=lambda folders: ready.set(), stop_event=stop), daemon=True)
    t.start()
    try:
        first = next_event(events)
        assert first.error and "blocker" in first.error and first.report.results == []
        assert ready.wait(TIMEOUT) and t.is_alive()
    finally:
        stop.set()
        t.join(TIMEOUT)
    assert not t.is_alive()
