"""The renderer's commands (validate, preview): an option out of its range is one usage error
(exit 2) naming the option, before anything is rendered."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from assetpipe.renderer.cli_commands import preview, validate


@pytest.mark.parametrize("command, args, message", [
    (validate, ["--size", "0"], "Invalid value for '--size': 0 is not in the range 16<=x<=16384"),
    (validate, ["--size", "8"], "Invalid value for '--size': 8 is not in the range 16<=x<=16384"),
    (validate, ["--size", "100000"], "Invalid value for '--size': 100000 is not in the range 16<=x<=16384"),
    (validate, ["--timeout", "0"], "Invalid value for '--timeout': 0.0 is not in the range x>0"),
    (validate, ["--timeout", "inf"], "Invalid value for '--timeout': inf is not a finite number"),
    (validate, ["--timeout", "nan"], "Invalid value for '--timeout': nan is not a finite number"),
    (preview, ["--size", "0"], "Invalid value for '--size': 0 is not in the range 1<=x<=16384"),
])
def test_an_option_out_of_range_is_a_usage_error(tmp_path, command, args, message):
    # (validate --size 0 failed every model one by one, --size 1 to 4 passed a model shrunk by
    # 10% (renderer/results.py, MIN_VALIDATE_SIZE), --timeout inf was a traceback, preview
    # --size 0 a ZeroDivisionError)
    target = tmp_path / "m.json"
    target.write_text("{}")
    r = CliRunner().invoke(command, [str(target), *args])
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit)
    assert message in r.output


@pytest.mark.parametrize("kw", [{"width": 8}, {"height": 15}, {"width": 0}, {"width": 16385}, {"width": 64.0},
                                {"height": True}])
def test_validate_options_refuse_a_size_the_checks_cannot_judge(kw):
    from assetpipe.renderer.results import ValidateOptions

    with pytest.raises(ValueError, match="must be an integer from 16 to 16384 pixels"):
        ValidateOptions(**kw)
    assert ValidateOptions(width=16, height=16384).width == 16
