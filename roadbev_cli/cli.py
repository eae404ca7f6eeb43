"""The ``roadbev`` entry point: one command, sub-commands per job (docs/interface/command-line.md).

Each sub-command lives in ``roadbev_cli/commands/<name>.py`` with ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only when their command
runs, so ``roadbev --help`` stays fast and ``roadbev eval --backend bm`` never imports rclpy.
Bad input (any :class:`roadbev_core.errors.RoadbevError`, or a file that cannot be opened) ends
with exit 2 and a one-line reason; anything else is a bug and keeps its traceback.

One prefix for everything a command says on stderr, argparse's own: ``roadbev <command>: error:
<reason>`` (:func:`error_line`) and ``roadbev <command>: warning: <what>`` (:func:`warn`). Lists
are space-separated everywhere (``--topics /a /b``, ``--features pothole crack``), as argparse's
``nargs`` reads them. Progress bars (:func:`progress_bar`) are drawn only when stderr is a
terminal, one unit per bar.
"""

from __future__ import annotations

import argparse
import importlib
import math
import shlex
import string
import sys
from collections.abc import Collection, Sequence
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as dist_version
from pathlib import Path
from typing import NoReturn

from roadbev_core.errors import RoadbevError
from roadbev_lab.progress import progress_bar

__all__ = [
    "COMMANDS", "CommandError", "add_output_flags", "error_line", "full_parser", "list_item", "main", "output_path",
    "progress_bar", "seconds", "shows_progress", "topic_name", "version", "warn",
]

# name -> one-line help (the module docstring says more)
COMMANDS: dict[str, str] = {
    "demo": "the main job: synthetic drive -> node over ROS 2 -> recorded outputs -> report",
    "synth": "write a synthetic evaluation/training bag (MCAP)",
    "eval": "run a backend over every frame of a bag (no DDS) and report the metrics",
    "replay": "publish a bag's topics over ROS 2 with their original timing",
    "record": "record topics to an MCAP bag",
    "bag": "what a bag holds (and whether it was closed cleanly); recover what is readable",
    "node": "run the RoadBEV node",
    "train": "train RoadBEV-mono / RoadBEV-stereo",
    "export": "export a checkpoint for deployment",
    "label": "label a recorded drive from its LiDAR: an evaluation/training bag with /ground_truth/elevation",
    "figures": "render the geometry and label figures (voxel columns, GT elevation map)",
}


class CommandError(RoadbevError):
    """A command refused its input; the message is the one-line reason shown to the user."""


def error_line(command: str, reason: object) -> str:
    """The one-line refusal of a command: ``roadbev <command>: error: <reason>``."""
    return f"roadbev {command}: error: {reason}"


def warn(command: str, text: str) -> None:
    """A warning on stderr: ``roadbev <command>: warning: <text>``."""
    print(f"roadbev {command}: warning: {text}", file=sys.stderr, flush=True)


def add_output_flags(parser: argparse.ArgumentParser, *, progress: bool = True, summary: bool = True) -> None:
    """The output flags every command spells the same way: ``--no-progress`` (no progress bar)
    where it draws one, ``--quiet`` (no progress bar and no summary: errors and warnings only)
    where it prints a summary."""
    if progress:
        parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    if summary:
        parser.add_argument("--quiet", action="store_true",
                            help="no progress bar and no summary (errors and warnings only)")


def shows_progress(args: argparse.Namespace) -> bool:
    """Whether a command draws its progress bar (:func:`add_output_flags`)."""
    return not (getattr(args, "no_progress", False) or getattr(args, "quiet", False))


def list_item(text: str) -> str:
    """argparse ``type`` of one item of a list option: lists are space-separated, so an item
    with a comma is refused with the way to write it (``--features pothole crack``)."""
    if "," in text:
        items = " ".join(item.strip() for item in text.split(",") if item.strip())
        raise argparse.ArgumentTypeError(f"lists are space-separated: write {items!r}, not {text!r}")
    return text


def seconds(text: str) -> float:
    """argparse ``type`` of a duration: a finite number of seconds, >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds >= 0, got {text!r}")
    return value


_TOPIC_CHARS = frozenset(string.ascii_letters + string.digits + "_/~")


def topic_name(text: str) -> str:
    """argparse ``type`` of a topic name, by the rules ROS 2 applies to one before any remapping
    (rcl's topic name validation): letters, digits, ``_`` and ``/``; no empty token (``//``), no
    trailing ``/``, no token starting with a digit; ``~`` only first, then ``/``. Substitutions
    (``{node}``) are refused: a command line names topics as they are."""
    name = list_item(text)
    bad = sorted(set(name) - _TOPIC_CHARS)
    reason = ""
    if not name:
        reason = "it is empty"
    elif bad:
        reason = f"{''.join(bad)!r} is not allowed (letters, digits, '_' and '/' only)"
    elif "~" in name[1:] or (name.startswith("~") and name[1:2] not in ("", "/")):
        reason = "'~' may only start the name, followed by '/'"
    elif name.endswith("/") and name != "/":
        reason = "it ends with '/'"
    elif name == "/":
        reason = "it names no topic"
    elif "//" in name:
        reason = "it has an empty token ('//')"
    elif any(token[:1].isdigit() for token in name.lstrip("~").split("/")):
        reason = "a token starts with a digit"
    if reason:
        raise argparse.ArgumentTypeError(f"not a ROS topic name: {text!r}: {reason}")
    return name


def output_path(text: str) -> Path:
    """argparse ``type`` of a file to write: its folder must exist (nothing is created unasked)."""
    path = Path(text)
    folder = path.parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(f"folder {folder} does not exist (for {text})")
    return path


def version() -> str:
    """The installed version of ``roadbev_ros`` (package.xml's, through setup.py)."""

    try:
        return dist_version("roadbev_ros")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _load(name: str):  # type: ignore[no-untyped-def]
    return importlib.import_module(f"roadbev_cli.commands.{name.replace('-', '_')}")


class _OneLineParser(argparse.ArgumentParser):
    """argparse without the usage block before a refusal: a bad command line is one line,
    ``roadbev <command>: error: <reason>``, as every other refusal (``--help`` shows the usage)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _build_parser(chosen: Collection[str]) -> argparse.ArgumentParser:
    """The parser with the arguments of the ``chosen`` commands; the others get only their
    one-line help."""
    parser = _OneLineParser(prog="roadbev", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"roadbev {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name in chosen:
            try:
                module = _load(name)
            except ModuleNotFoundError as exc:
                if exc.name and exc.name.startswith("roadbev_cli.commands"):
                    p.set_defaults(_missing=f"'{name}' is not available in this build")
                    continue
                raise
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def full_parser() -> argparse.ArgumentParser:
    """The parser of ``roadbev`` with every command's arguments (the documentation's; a command
    line builds only its own command's, so that ``roadbev --help`` stays fast)."""
    return _build_parser(COMMANDS)


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    chosen = next((a for a in args_list if not a.startswith("-")), None)
    if chosen is not None and chosen not in COMMANDS:
        print(f"roadbev: error: unknown command {chosen!r} (choose from {', '.join(COMMANDS)})", file=sys.stderr)
        return 2
    # Only the chosen command's module is imported: the others show their one-line help.
    parser = _build_parser(() if chosen is None else (chosen,))
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help()
        return 2
    if getattr(args, "_missing", None):
        print(error_line(args.command, args._missing), file=sys.stderr)
        return 2
    args.command_line = shlex.join(["roadbev", *args_list])  # what a command records of how it was run
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print(error_line(args.command, "interrupted"), file=sys.stderr)
        return 130
    except (RoadbevError, OSError) as exc:  # bad input; a programming error keeps its traceback
        print(error_line(args.command, exc), file=sys.stderr)
        return 2


if __name__ == "__main__":
    # Run through the imported module, not this __main__ copy, so that the CommandError raised by
    # commands (roadbev_cli.cli.CommandError) is the class caught above.
    from roadbev_cli.cli import main as _main

    sys.exit(_main())
