"""The renderer's commands (validate, preview): an option out of its range is one usage error
(exit 2) naming the option, before anything is rendered."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from assetpipe.renderer.cli_commands import preview, validate


@pytest.mark.parametrize("command, args, message", [
    (validate, ["--size", "0"], "Invalid value for '--size': 0 is not in the range 1<=x<=16384"),
    (validate, ["--size", "100000"], "Invalid value for '--size': 100000 is not in the range 1<=x<=16384"),
    (validate, ["--timeout", "0"], "Invalid value for '--timeout': 0.0 is not in the range x>0"),
    (validate, ["--timeout", "inf"], "Invalid value for '--timeout': inf is not a finite number"),
    (validate, ["--timeout", "nan"], "Invalid value for '--timeout': nan is not a finite number"),
    (preview, ["--size", "0"], "Invalid value for '--size': 0 is not in the range 1<=x<=16384"),
])
def test_an_option_out_of_range_is_a_usage_error(tmp_path, command, args, message):
    # (validate --size 0 failed every model one by one, --timeout inf was a traceback, preview
    # --size 0 a ZeroDivisionError)
    target = tmp_path / "m.json"
    target.write_text("{}")
    r = CliRunner().invoke(command, [str(target), *args])
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit)
    assert message in r.output
