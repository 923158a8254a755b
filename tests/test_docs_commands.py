"""Every command line written in README.md and docs/ (fenced ``sh`` blocks) still works, so the docs
cannot drift from the program.

A concrete command (``assetpipe build examples -o out && ...``) is run, in a scratch folder holding
a copy of ``examples/``, with a cache of its own; a synopsis (``assetpipe build INPUT... [-o OUT]``,
recognised by its ``[...]``, ``...`` or upper-case placeholders) is checked option by option against
the command's ``--help``; ``bash scripts/x.sh`` lines (setup installs Debian packages, test runs this
suite) are checked to exist and to parse (``bash -n``); ``python x.py`` lines to exist and answer
``--help``. Any other kind of line fails: add a rule here rather than leave it unchecked.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), REPO / "benchmarks" / "README.md"]
FENCE = re.compile(r"^```(?:sh|bash|shell)\n(.*?)^```", re.S | re.M)
PLACEHOLDER = re.compile(r"\[|\.\.\.|\b[A-Z]{2,}\b")
OPTION = re.compile(r"(?<![\w/])(--?[a-zA-Z][-a-zA-Z0-9]*)")
# the validate engineer renames validate's --json-report to --json: accept either until both land
SPELLINGS = {"--json": ("--json", "--json-report")}


def command_lines() -> list[tuple[str, int, str]]:
    """(doc, line number, command) for every command line of every fenced sh block."""
    found = []
    for doc in DOCS:
        if not doc.is_file():
            continue
        text = doc.read_text(encoding="utf-8")
        for block in FENCE.finditer(text):
            first = text[: block.start(1)].count("\n") + 1
            logical: list[tuple[int, str]] = []
            for i, raw in enumerate(block.group(1).splitlines()):
                line = re.sub(r"\s+#.*$", "", raw).rstrip()
                if not line.strip() or line.lstrip().startswith("#"):
                    continue
                if logical and (raw[:1].isspace() or logical[-1][1].endswith("\\")):
                    logical[-1] = (logical[-1][0], logical[-1][1].rstrip("\\") + " " + line.strip())
                else:
                    logical.append((first + i, line.strip()))
            found += [(doc.relative_to(REPO).as_posix(), n, cmd) for n, cmd in logical]
    return found


COMMANDS = command_lines()


def _assetpipe(tokens: list[str]) -> list[str] | None:
    if tokens and Path(tokens[0]).name == "assetpipe":
        return [sys.executable, "-m", "assetpipe.cli", *tokens[1:]]
    return None


def _env(tmp: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(REPO), "ASSETPIPE_CACHE": str(tmp / "cache"),
            "VK_DRIVER_FILES": os.environ.get("VK_DRIVER_FILES", "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")}


def _check_synopsis(cmd: str, tokens: list[str], tmp: Path) -> None:
    words = [t for t in tokens[1:] if re.fullmatch(r"[a-z][-a-z]*", t)]
    sub = []
    for w in words:  # the subcommand path: 'build', 'cache gc', ...
        probe = subprocess.run([sys.executable, "-m", "assetpipe.cli", *sub, w, "--help"], capture_output=True,
                               text=True, env=_env(tmp))
        if probe.returncode != 0:
            break
        sub.append(w)
    assert sub, f"{cmd!r}: no assetpipe command in it"
    help_text = subprocess.run([sys.executable, "-m", "assetpipe.cli", *sub, "--help"], capture_output=True,
                               text=True, check=True, env=_env(tmp)).stdout
    for opt in OPTION.findall(cmd[cmd.index(sub[-1]) + len(sub[-1]):]):
        spellings = SPELLINGS.get(opt, (opt,))
        assert any(re.search(rf"(?<![-\w]){re.escape(s)}\b", help_text) for s in spellings), \
            f"{cmd!r}: 'assetpipe {' '.join(sub)}' has no option {opt}"


@pytest.mark.parametrize("doc, line, cmd", COMMANDS, ids=[f"{d}:{n}" for d, n, _ in COMMANDS])
def test_documented_command_works(doc, line, cmd, tmp_path):
    work = tmp_path / "work"
    shutil.copytree(REPO / "examples", work / "examples", ignore=shutil.ignore_patterns("*.py"))
    for part in (p.strip() for p in cmd.split("&&")):
        tokens = shlex.split(part)
        run = _assetpipe(tokens)
        if run is not None:
            if PLACEHOLDER.search(part):
                _check_synopsis(part, tokens, tmp_path)
                continue
            r = subprocess.run(run, cwd=work, capture_output=True, text=True, env=_env(tmp_path), timeout=600)
            assert r.returncode == 0, f"{doc}:{line}: {part!r} exited {r.returncode}\n{r.stdout}\n{r.stderr}"
        elif tokens[:1] == ["bash"] and tokens[1].endswith(".sh"):
            script = REPO / tokens[1]
            assert script.is_file(), f"{doc}:{line}: {tokens[1]} does not exist"
            subprocess.run(["bash", "-n", str(script)], check=True)
        elif tokens and Path(tokens[0]).name.startswith("python") and tokens[1].endswith(".py"):
            script = REPO / tokens[1]
            assert script.is_file(), f"{doc}:{line}: {tokens[1]} does not exist"
            subprocess.run([sys.executable, str(script), "--help"], check=True, capture_output=True,
                           env=_env(tmp_path), timeout=120)
        elif tokens[:1] == ["dask"] and tokens[1:2] in (["scheduler"], ["worker"]):
            # the farm's scheduler and workers (docs/FARM.md; tests/test_farm.py runs a real
            # LocalCluster): the documented flags must be the installed dask CLI's
            dask = Path(sys.executable).with_name("dask")
            if not dask.exists():
                pytest.skip("the farm extra is not installed (pip install 'assetpipe[farm]')")
            help_text = subprocess.run([str(dask), tokens[1], "--help"], capture_output=True, text=True,
                                       check=True, timeout=120).stdout
            for opt in (t for t in tokens[2:] if t.startswith("--")):
                assert opt in help_text, f"{doc}:{line}: 'dask {tokens[1]}' has no option {opt}"
        else:
            pytest.fail(f"{doc}:{line}: no rule checks {part!r}: add one to tests/test_docs_commands.py")


def test_the_readme_commands_are_found():
    cmds = [c for d, _, c in COMMANDS if d == "README.md"]
    assert any(c.startswith("bash scripts/setup.sh && ") and "assetpipe validate out" in c for c in cmds)
    assert "bash scripts/test.sh" in cmds
    assert any(c.startswith("assetpipe build INPUT...") and "--max-texture-size" in c for c in cmds)
