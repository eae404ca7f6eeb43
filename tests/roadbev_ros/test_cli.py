from __future__ import annotations

import subprocess
import sys

import pytest

from roadbev_ros import cli


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in cli.COMMANDS:
        assert name in out


def test_no_command_prints_help_and_fails(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_unknown_command_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["fly"])
    assert exc.value.code == 2


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_command_has_help(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: roadbev " + name in capsys.readouterr().out


def test_console_entry_point_runs() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "roadbev_ros.cli", "--help"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and "roadbev" in proc.stdout


def test_bad_input_is_one_line_and_a_bug_keeps_its_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import types

    from roadbev_core.errors import RoadbevError
    from roadbev_ros import cli

    def command(error: Exception) -> types.SimpleNamespace:
        def run(_args: object) -> int:
            raise error

        return types.SimpleNamespace(add_arguments=lambda _parser: None, run=run)

    monkeypatch.setattr(cli, "_load", lambda _name: command(RoadbevError("the bag has no frames")))
    assert cli.main(["eval"]) == 2
    assert capsys.readouterr().err == "roadbev eval: the bag has no frames\n"
    monkeypatch.setattr(cli, "_load", lambda _name: command(ValueError("a bug")))
    with pytest.raises(ValueError, match="a bug"):  # not hidden as "bad input"
        cli.main(["eval"])
