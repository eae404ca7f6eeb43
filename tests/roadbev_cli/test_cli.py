from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from roadbev_cli import cli


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


def test_unknown_command_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["fly"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"roadbev: error: unknown command 'fly' (choose from {', '.join(cli.COMMANDS)})"]


@pytest.mark.parametrize("argv, reason", [
    (["eval", "b.mcap", "--lead-time", "-1"], "argument --lead-time: must be a finite number of seconds >= 0"),
    (["eval", "b.mcap", "--lead-time", "nan"], "argument --lead-time: must be a finite number of seconds >= 0"),
    (["record", "{missing}/r.mcap", "--topics", "/a"], "argument out: folder {missing} does not exist"),
    (["bag", "info", "b.mcap", "--json", "{missing}/i.json"], "argument --json: folder {missing} does not exist"),
    (["record", "o.mcap", "--topics", "not a topic!"], "not a ROS topic name: 'not a topic!'"),
    (["record", "o.mcap", "--topics", "/a//b"], "it has an empty token"),
    (["replay", "b.mcap", "--topics", "/cam/0left"], "a token starts with a digit"),
    (["replay", "b.mcap", "--rate", "inf"], "--rate must be 0 (as fast as possible) or in [0.001, 1000], got inf"),
    (["replay", "b.mcap", "--rate", "1e-300"], "--rate must be 0 (as fast as possible) or in [0.001, 1000]"),
])
def test_bad_command_lines_are_refused_in_one_line_before_any_work(
        argv: list[str], reason: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nowhere"
    bag = tmp_path / "b.mcap"
    bag.write_bytes(b"")
    args = [a.replace("b.mcap", str(bag)).replace("o.mcap", str(tmp_path / "o.mcap")).format(missing=missing)
            for a in argv]
    try:
        code = cli.main(args)
    except SystemExit as exc:  # argparse's refusal
        code = int(exc.code or 0)
    assert code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"roadbev {argv[0]}") and ": error: " in lines[0], lines
    assert reason.format(missing=missing) in lines[0]
    assert not missing.exists()  # no folder created unasked


@pytest.mark.parametrize("name", ["/stereo/left/image_rect", "imu", "~/save_map", "/a_1/b2"])
def test_valid_topic_names_pass(name: str) -> None:
    assert cli.topic_name(name) == name


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_command_has_help(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main([name, "--help"])
    assert exc.value.code == 0
    assert "usage: roadbev " + name in capsys.readouterr().out


def test_console_entry_point_runs() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "roadbev_cli.cli", "--help"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and "roadbev" in proc.stdout


def test_bad_input_is_one_line_and_a_bug_keeps_its_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import types

    from roadbev_cli import cli
    from roadbev_core.errors import RoadbevError

    def command(error: Exception) -> types.SimpleNamespace:
        def run(_args: object) -> int:
            raise error

        return types.SimpleNamespace(add_arguments=lambda _parser: None, run=run)

    monkeypatch.setattr(cli, "_load", lambda _name: command(RoadbevError("the bag has no frames")))
    assert cli.main(["eval"]) == 2
    assert capsys.readouterr().err == "roadbev eval: error: the bag has no frames\n"
    monkeypatch.setattr(cli, "_load", lambda _name: command(ValueError("a bug")))
    with pytest.raises(ValueError, match="a bug"):  # not hidden as "bad input"
        cli.main(["eval"])


def test_version_is_package_xml_s(capsys: pytest.CaptureFixture[str]) -> None:
    import re
    from pathlib import Path

    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    xml = (Path(__file__).resolve().parents[2] / "package.xml").read_text()
    found = re.search(r"<version>([^<]+)</version>", xml)
    assert found is not None
    assert capsys.readouterr().out.strip() == f"roadbev {found.group(1)}"


@pytest.mark.parametrize("argv", [
    ["figures", "--features", "pothole,crack"],
    ["synth", "out.mcap", "--features", "pothole,crack"],
    ["replay", "bag.mcap", "--topics", "/a,/b"],
    ["record", "out.mcap", "--topics", "/a,/b"],
])
def test_lists_are_space_separated_everywhere(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith(f"roadbev {argv[0]}: error: ") and "lists are space-separated" in err, err


def test_figures_takes_its_features_space_separated(tmp_path: object, monkeypatch: pytest.MonkeyPatch) -> None:
    import argparse

    from roadbev_cli.commands import figures

    parser = argparse.ArgumentParser()
    figures.add_arguments(parser)
    assert parser.parse_args(["--features", "pothole", "crack"]).features == ["pothole", "crack"]
    assert parser.parse_args(["--features"]).features == []
    assert parser.parse_args([]).features == list(figures.DEFAULT_FEATURES)
    with pytest.raises(SystemExit):
        parser.parse_args(["--features", "volcano"])


@pytest.mark.parametrize("argv", [
    ["replay", "/nonexistent/bag.mcap"],
    ["eval", "/nonexistent/bag.mcap"],
    ["bag", "info", "/nonexistent/bag.mcap"],
    ["record", "README.md", "--topics", "/a"],
    ["node", "--params", "/nonexistent/params.yaml"],
])
def test_every_command_refuses_with_one_prefix(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"roadbev {argv[0]}: error: "), err


def test_replay_of_unknown_topics_says_so_in_a_sentence() -> None:
    from pathlib import Path

    sample = Path(__file__).resolve().parents[2] / "bags" / "sample_drive.mcap"
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "replay", str(sample), "--topics", "/nope",
                           "--no-wait"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert err.startswith("roadbev replay: error: nothing to replay from ") and "/nope: not in the bag" in err
    assert "{" not in err and "/imu/data" in err  # a sentence naming what the bag holds, not a dict


@pytest.mark.parametrize("tty", [False, True])
def test_progress_bars_only_on_a_terminal(tty: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    stream = io.StringIO()
    monkeypatch.setattr(stream, "isatty", lambda: tty)
    monkeypatch.setattr(sys, "stderr", stream)
    bar = cli.progress_bar(unit="frame", desc="eval", total=3)
    for _ in range(3):
        bar.update(1)
    bar.close()
    assert ("\r" in stream.getvalue()) == tty
    assert ("frame" in stream.getvalue()) == tty
    if tty:
        assert "3/3" in stream.getvalue()


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_option_has_help_and_the_output_flags_are_spelled_one_way(name: str) -> None:
    import argparse
    import inspect

    module = cli._load(name)
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    groups = [parser] + [a.choices[c] for a in parser._actions if isinstance(a, argparse._SubParsersAction)
                         for c in a.choices]
    source = inspect.getsource(module)
    for group in groups:
        for action in group._actions:
            if action.option_strings and not isinstance(action, argparse._HelpAction):
                assert action.help, f"roadbev {name} {action.option_strings[0]} has no help"
        flags = {o: a.help for a in group._actions for o in a.option_strings}
        if "--quiet" in flags:
            assert flags["--quiet"] == "no progress bar and no summary (errors and warnings only)"
        if "--no-progress" in flags:
            assert flags["--no-progress"] == "no progress bar"
    options = {o for group in groups for a in group._actions for o in a.option_strings}
    if "progress_bar(" in source or "progress=shows_progress" in source:  # the command draws a bar
        assert "--no-progress" in options, f"roadbev {name} draws a progress bar without --no-progress"


def _options(parser: argparse.ArgumentParser) -> dict[str, list[str]]:
    """Every command's option strings and destinations, by command (sub-commands too)."""
    out: dict[str, list[str]] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[name] = sorted(o or a.dest for a in sub._actions for o in a.option_strings or [""])
                out.update({f"{name} {k}": v for k, v in _options(sub).items()})
    return out


def test_the_full_parser_holds_every_command_as_its_own_command_line_builds_it() -> None:
    full = _options(cli.full_parser())
    assert set(cli.COMMANDS) <= set(full)
    for name in cli.COMMANDS:
        alone = _options(cli._build_parser((name,)))
        assert {k: v for k, v in full.items() if k == name or k.startswith(f"{name} ")} == {
            k: v for k, v in alone.items() if k == name or k.startswith(f"{name} ")}
        assert len(full[name]) > 1, f"roadbev {name} has no arguments in the full parser"
