"""The recipes of the README and the tutorials, checked as a user pastes them.

The replay-and-record block is taken from ``docs/tutorials/replay_and_evaluate.md`` itself and runs
in bash with job control (as in a terminal: ``&`` jobs, ``%1``), in a scratch folder holding
``.venv/bin/roadbev`` (this interpreter with this checkout) and ``bags/`` (the repository's), so
every line is executed unchanged. Every params YAML block on those pages is a params file the node
accepts, and every topic a ``roadbev node`` block remaps is one the node subscribes by default.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from msg_bridge import bag, stamp_from_header
from roadbev_core.config import RoadbevConfig, load_params_file
from roadbev_ros.dds import child_env
from roadbev_ros.diagnostics import DROP_KINDS

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "bags" / "sample_drive.mcap"
SAMPLE_FRAMES = 20
REPLAY_PAGE = ROOT / "docs" / "tutorials" / "replay_and_evaluate.md"
REPLAY_LEAD = "Replay a bag into the node and record"
# The pages whose recipes a user pastes: the README and the tutorials.
RECIPE_PAGES = [ROOT / "README.md", *sorted((ROOT / "docs" / "tutorials").glob("*.md"))]


def shell_block_after(text: str, lead: str) -> str:
    """The first fenced ``sh`` block after the paragraph that starts with ``lead``."""
    start = text.index(lead)
    found = re.compile(r"```sh\n(.*?)```", re.DOTALL).search(text, start)
    assert found is not None, f"no sh block after {lead!r}"
    return found.group(1)


def fenced_blocks(text: str, language: str) -> list[str]:
    """Every fenced block of ``language`` on a page."""
    return re.findall(rf"```{language}\n(.*?)```", text, re.DOTALL)


def _page_id(page: Path) -> str:
    return str(page.relative_to(ROOT))


@pytest.mark.parametrize("page", RECIPE_PAGES, ids=_page_id)
def test_every_params_block_is_a_params_file_the_node_accepts(page: Path, tmp_path: Path) -> None:
    for i, block in enumerate(b for b in fenced_blocks(page.read_text(), "yaml") if "ros__parameters" in b):
        path = tmp_path / f"block{i}.yaml"
        path.write_text(block)
        RoadbevConfig.from_params(load_params_file(path).values)  # raises, naming the parameter


@pytest.mark.parametrize("page", RECIPE_PAGES, ids=_page_id)
def test_every_remapped_topic_is_one_the_node_subscribes(page: Path) -> None:
    defaults = {v for k, v in RoadbevConfig().to_params().items() if k.endswith("_topic") and v}
    node_blocks = [b for b in fenced_blocks(page.read_text(), "sh") if "roadbev node" in b]
    remapped = [m for b in node_blocks for m in re.findall(r"-r (\S+):=", b)]
    assert set(remapped) <= defaults, set(remapped) - defaults


def test_the_recipe_block_is_found_and_starts_the_recorder_before_the_blocking_replay() -> None:
    block = shell_block_after(REPLAY_PAGE.read_text(), REPLAY_LEAD)
    lines = [line for line in block.splitlines() if line.strip()]
    record = next(i for i, line in enumerate(lines) if " record " in line)
    replay = next(i for i, line in enumerate(lines) if " replay " in line)
    assert lines[record].rstrip().endswith("&") and not lines[replay].rstrip().endswith("&")
    assert record < replay


@pytest.fixture
def user_folder(tmp_path: Path) -> Path:
    """A folder laid out like the repository root after ``make setup``."""
    bin_dir = tmp_path / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    roadbev = bin_dir / "roadbev"
    roadbev.write_text(f'#!/bin/sh\nPYTHONPATH="{ROOT}${{PYTHONPATH:+:$PYTHONPATH}}" '
                       f'exec "{sys.executable}" -m roadbev_cli.cli "$@"\n')
    roadbev.chmod(0o755)
    (tmp_path / "bags").symlink_to(ROOT / "bags")
    return tmp_path


@pytest.fixture
def shell() -> Iterator[list[subprocess.Popen[bytes]]]:
    """Shells started by a test; their whole process group is killed in teardown."""
    procs: list[subprocess.Popen[bytes]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)


def diagnostics_values(msg: object) -> dict[str, str]:
    status = msg.status[0]  # type: ignore[attr-defined]
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.skipif(not SAMPLE.exists(), reason="bags/sample_drive.mcap is not in this checkout")
def test_replay_into_the_node_and_record(user_folder: Path, shell: list[subprocess.Popen[bytes]]) -> None:
    block = shell_block_after(REPLAY_PAGE.read_text(), REPLAY_LEAD)
    log = user_folder / "shell.log"
    with log.open("wb") as out:
        # set -m: job control as in a terminal (background jobs keep SIGINT; %1 names a job)
        proc = subprocess.Popen(["bash", "-c", "set -m\n" + block], cwd=user_folder, stdout=out,
                                stderr=subprocess.STDOUT, env=child_env(), start_new_session=True)
    shell.append(proc)
    assert proc.wait(120) == 0, log.read_text()
    text = log.read_text()
    assert "no subscriber" not in text, text  # the replay found the node's subscriptions in time
    recorded = user_folder / "out.mcap"
    topics = bag.bag_topics(recorded)
    assert set(topics) == {"/roadbev/elevation", "/roadbev/preview", "/diagnostics"}, text
    diagnostics = [m.msg for m in bag.read_messages(recorded, ["/diagnostics"])]
    final = diagnostics_values(diagnostics[-1])
    outputs = int(final["outputs"])
    drops = sum(int(final[k]) for k in DROP_KINDS)
    # every frame of the bag reached the node, and each is an output or a counted drop
    assert int(final["frames_in"]) == SAMPLE_FRAMES, final
    assert outputs + drops == SAMPLE_FRAMES, final
    assert outputs >= 1
    # the node ran on the bag's clock (use_sim_time, replay --clock): its stamps were never "old"
    stamp_checks = [m.status[2] for m in diagnostics]
    assert all(s.name == "roadbev: left image stamps" for s in stamp_checks)
    assert not any("old on arrival" in s.message or "ahead of" in s.message for s in stamp_checks), \
        [s.message for s in stamp_checks]
    # the recording holds every output the node published (on failure: which stamps it holds, and the log)
    recorded_stamps = [stamp_from_header(m.msg) for m in bag.read_messages(recorded, ["/roadbev/elevation"])]
    assert topics["/roadbev/elevation"].count == outputs, (final, recorded_stamps, text)
    assert topics["/roadbev/preview"].count == outputs, (final, text)
