"""``roadbev bag info BAG`` and ``roadbev bag recover BAG OUT``: what a bag holds; a copy of what is readable.

``info`` lists the topics with their types and readable message counts, says whether the bag was
closed cleanly (summary and footer written, no ``.recording`` marker left by a writer that was
killed) and names every damaged part (file, chunk, byte offset, reason, messages lost). By
default every chunk is decompressed and its CRC checked; ``--no-verify`` reads the indexes only.

``recover`` writes a complete, indexed bag (``OUT.mcap`` or a rosbag2 directory) with every
message of every sound chunk, byte for byte, on the original topics, types and QoS; damaged and
cut chunks are left out and counted. It works on unfinished bags (a crashed ``roadbev record``)
and on damaged ones; on a sound bag it makes an exact copy of the messages.

Both exit 0 when something was readable and 2 when nothing was (docs/interface/command-line.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from msg_bridge.bag import bag_info, recover_bag
from roadbev_cli.cli import add_output_flags, output_path, progress_bar, shows_progress

HELP = "what a bag holds (and whether it was closed cleanly); recover what is readable"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev bag``."""
    sub = parser.add_subparsers(dest="bag_command", metavar="ACTION", required=True)
    info = sub.add_parser("info", help="topics, message counts, clean close, damage",
                          description="topics, message counts, clean close, damage")
    info.add_argument("bag", type=Path, metavar="BAG", help="rosbag2 directory or .mcap file")
    info.add_argument("--no-verify", action="store_true", help="read the indexes only (no CRC check of the chunks)")
    info.add_argument("--json", type=output_path, default=None, metavar="OUT",
                      help="also write the report as JSON here")
    recover = sub.add_parser("recover", help="a complete, indexed copy of everything readable",
                             description="a complete, indexed copy of everything readable")
    recover.add_argument("bag", type=Path, metavar="BAG", help="rosbag2 directory or .mcap file (unfinished, damaged)")
    recover.add_argument("out", type=output_path, metavar="OUT",
                         help="the copy: .mcap or rosbag2 directory (must not exist; its folder must)")
    recover.add_argument("--compression", choices=("zstd", "none"), default="zstd",
                         help="MCAP chunk compression of the copy (default zstd)")
    add_output_flags(recover, summary=False)


def run(args: argparse.Namespace) -> int:
    """Run ``info`` or ``recover``; a bag with nothing readable raises (exit 2)."""

    if args.bag_command == "info":
        info = bag_info(args.bag, verify=not args.no_verify)
        print("\n".join(info.lines()))
        if args.json:
            args.json.write_text(json.dumps(info.to_dict(), indent=2) + "\n")
        return 0
    if args.out.exists():
        raise OSError(f"{args.out} exists already; not overwriting it")
    bar = progress_bar(unit="msg", desc="recover", disable=not shows_progress(args), leave=False)
    try:
        stats = recover_bag(args.bag, args.out, compression=args.compression, progress=bar.update)
    finally:
        bar.close()
    print(f"recovered {sum(stats.read.values())} message(s) to {args.out}: {stats.summary()}")
    return 0
