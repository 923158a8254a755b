"""The build command's options: a value out of its option's range is one usage error (exit 2)
naming the option, never a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from assetpipe.cli import eval_ratio, main

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("args, message", [
    (["--max-model-mb", "inf"], "Invalid value for '--max-model-mb': inf is not a finite number"),
    (["--max-model-mb", "nan"], "Invalid value for '--max-model-mb': nan is not a finite number"),
    (["--max-coordinate", "inf"], "Invalid value for '--max-coordinate': inf is not a finite number"),
    (["--max-output-mb", "inf"], "Invalid value for '--max-output-mb': inf is not a finite number"),
    (["--lod-max-error", "nan"], "Invalid value for '--lod-max-error': nan is not a finite number"),
    (["--lod-max-error", "inf"], "Invalid value for '--lod-max-error': inf is not a finite number"),
    (["--lod-max-error", "-1"], "Invalid value for '--lod-max-error': -1.0 is not in the range x>=0"),
    (["--lod-ratios", "1,1/0"], "the ratio '1/0' divides by zero"),
])
def test_an_option_out_of_range_is_a_usage_error(tmp_path: Path, args, message):
    # (each of these was a traceback: int(inf) of a size, inf in the options' JSON, 1/0)
    shutil.copytree(REPO / "examples" / "pyramid", tmp_path / "art")
    r = CliRunner().invoke(main, ["build", str(tmp_path / "art"), "-o", str(tmp_path / "out"),
                                  "--cache", str(tmp_path / "cache"), "-j", "1", *args])
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit)
    assert message in r.output
    assert not (tmp_path / "out").exists()


def test_ratios_are_read_as_numbers_or_fractions():
    assert eval_ratio(" 1/4 ") == 0.25 and eval_ratio("0.5") == 0.5
    with pytest.raises(ValueError, match="divides by zero"):
        eval_ratio("1/0")
    with pytest.raises(ValueError):
        eval_ratio("1/x")


def test_process_entry_keeps_exit_codes_output_and_exit_handlers(tmp_path):
    """``run`` (the script's entry) ends the process with os._exit: the command's exit code,
    its output flushed into a pipe, and the exit handlers run all the same."""
    import subprocess
    import sys

    def entry(*argv: str) -> subprocess.CompletedProcess:
        code = ("import atexit, sys\nfrom assetpipe import cli\n"
                "atexit.register(lambda: print('exit handler ran'))\n"
                f"sys.argv = ['assetpipe', *{list(argv)!r}]\ncli.run()\nprint('not reached')\n")
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)

    ok = entry("--version")
    assert ok.returncode == 0, ok.stderr
    assert "assetpipe, version" in ok.stdout and "exit handler ran" in ok.stdout
    assert "not reached" not in ok.stdout
    missing = entry("build", str(tmp_path / "missing.gltf"))
    assert missing.returncode == 1 and "no such file or folder" in missing.stderr
    assert "exit handler ran" in missing.stdout
    usage = entry("build", "--no-such-option")
    assert usage.returncode == 2 and "No such option" in usage.stderr and "exit handler ran" in usage.stdout
