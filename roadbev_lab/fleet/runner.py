"""Many bags through one command: find them, key them, run what is not done, keep every result.

:func:`find_bags` turns the command line's BAG arguments (bags, folders of bags, glob patterns)
into a sorted list of bags. :func:`run_bags` runs a :class:`~roadbev_lab.fleet.tasks.BagJob` per bag
on an executor:

1. the content digest of every bag (remembered by its files' names, sizes and times, so only
   new or changed bags are read; on the executor: hashing a large archive is work too);
2. each bag's key (content and configuration): a bag whose key is in the store (and whose output
   exists, for ``roadbev label``) is done already and is skipped, unless ``resume`` is off; a bag
   with the content of one before it is a duplicate (run and pooled once);
3. the rest as tasks; each finished result goes into the store as it arrives, in this process.

A bag that fails (cannot be read, refused by the command) is reported with its reason; its key is
not stored, so the next run tries it again.
"""

from __future__ import annotations

import glob
import hashlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roadbev_lab.fleet.executors import Executor, Outcome
from roadbev_lab.fleet.store import ResultStore, result_key
from roadbev_lab.fleet.tasks import BagJob, BagResult, EvalSettings, LabelSettings, bag_digest, run_job

__all__ = ["DONE", "DUPLICATE", "FAILED", "STORED", "BagOutcome", "find_bags", "is_bag", "output_names", "run_bags"]

DONE, STORED, FAILED, DUPLICATE = "done", "stored", "failed", "duplicate"  # a bag's status in a run
_GLOB_CHARS = frozenset("*?[")


@dataclass(frozen=True)
class BagOutcome:
    """What became of one bag in a run.

    Attributes:
        bag: the bag.
        status: ``done`` (run now), ``stored`` (its result was in the store), ``failed`` or
            ``duplicate`` (the same content as an earlier bag of the list).
        key: its store key (None when its content could not be read).
        error: why it failed, or which bag it duplicates.
    """

    bag: Path
    status: str
    key: str | None = None
    error: str | None = None


def is_bag(path: Path) -> bool:
    """A bag by itself: an ``.mcap`` file, or a rosbag2 directory (with ``metadata.yaml``)."""
    return (path.is_file() and path.suffix == ".mcap") or (path.is_dir() and (path / "metadata.yaml").is_file())


def _bags_below(folder: Path) -> Iterable[Path]:
    """The bags in a folder and its sub-folders: rosbag2 directories, and ``.mcap`` files outside them."""
    for entry in sorted(folder.iterdir()):
        if is_bag(entry):
            yield entry
        elif entry.is_dir() and not entry.name.startswith("."):
            yield from _bags_below(entry)


def find_bags(specs: Sequence[str | Path]) -> list[Path]:
    """The bags the command line names, in order, each once.

    Each spec is a bag, a folder (every bag in it and below: rosbag2 directories, ``.mcap``
    files), or a glob pattern (``'archive/2024-*/*.mcap'``, ``**`` for any depth) whose matches are
    bags or folders.

    Raises:
        FileNotFoundError: a spec that is neither, or a pattern or folder without a bag.
    """
    found: list[Path] = []
    for spec in specs:
        path = Path(spec)
        if path.exists():
            matches = [path]
        elif _GLOB_CHARS & set(str(spec)):
            # glob.glob, not Path.glob: the pattern may be absolute
            matches = [Path(m) for m in sorted(glob.glob(str(spec), recursive=True))]  # noqa: PTH207
        else:
            raise FileNotFoundError(f"bag not found: {spec}")
        bags: list[Path] = []
        for match in matches:
            if is_bag(match):
                bags.append(match)
            elif match.is_dir():
                bags.extend(_bags_below(match))
        if not bags:
            raise FileNotFoundError(f"no bags in {spec}" if path.exists() else f"no bags match {spec}")
        found.extend(bags)
    seen: set[Path] = set()
    unique = []
    for bag in found:
        if bag.resolve() not in seen:
            seen.add(bag.resolve())
            unique.append(bag)
    return unique


def output_names(bags: Sequence[Path]) -> dict[Path, str]:
    """A file name per bag for its output in one folder: the bag's own name (``.mcap``), with a
    short digest of its path where two bags share a name."""
    stems = [b.stem if b.suffix == ".mcap" else b.name for b in bags]
    out = {}
    for bag, stem in zip(bags, stems, strict=True):
        if stems.count(stem) > 1:
            stem = f"{stem}-{hashlib.sha256(str(bag.resolve()).encode()).hexdigest()[:8]}"
        out[bag] = f"{stem}.mcap"
    return out


def run_bags(
    bags: Sequence[Path],
    settings: EvalSettings | LabelSettings,
    config_digest: str,
    executor: Executor,
    store: ResultStore,
    *,
    resume: bool = True,
    outputs: dict[Path, Path] | None = None,
    task: Callable[[BagJob], BagResult] = run_job,
    progress: Callable[[BagOutcome], object] | None = None,
) -> list[BagOutcome]:
    """Run every bag not done yet (see the module docstring); one :class:`BagOutcome` per bag, in order.

    Args:
        bags: the bags (:func:`find_bags`).
        settings: what every bag runs with.
        config_digest: the digest of the configuration (:func:`roadbev_lab.fleet.store.config_digest`).
        executor: where the tasks run.
        store: where finished results are kept.
        resume: skip bags whose result is in the store (False: run every bag again).
        outputs: bag -> the file its task writes (``roadbev label``); a stored result counts as
            done only while that file exists.
        task: the function a worker runs on a :class:`BagJob` (:func:`roadbev_lab.fleet.tasks.run_job`).
        progress: called with each bag's outcome as it is known.
    """
    result: dict[int, BagOutcome] = {}

    def settle(index: int, outcome: BagOutcome) -> None:
        result[index] = outcome
        if progress is not None:
            progress(outcome)

    digests = {i: store.cached_digest(bag) for i, bag in enumerate(bags)}
    unknown = [i for i, d in digests.items() if d is None]
    for i, hashed in zip(unknown, executor.run(bag_digest, [bags[i] for i in unknown]), strict=True):
        if hashed.ok and isinstance(hashed.value, str):
            digests[i] = hashed.value
            store.remember_digest(bags[i], hashed.value)
        else:
            settle(i, BagOutcome(bags[i], FAILED, error=f"cannot read it: {hashed.error}"))
    jobs: list[tuple[int, BagJob]] = []
    first_of: dict[str, Path] = {}
    for i, bag in enumerate(bags):
        digest = digests[i]
        if digest is None:
            continue
        key = result_key(digest, config_digest)
        if key in first_of:
            settle(i, BagOutcome(bag, DUPLICATE, key, f"the same content as {first_of[key]}"))
            continue
        first_of[key] = bag
        out = None if outputs is None else outputs[bag]
        if resume and store.has(key) and (out is None or out.exists()):
            settle(i, BagOutcome(bag, STORED, key))
        else:
            jobs.append((i, BagJob(bag, key, settings, out)))

    def on_done(j: int, outcome: Outcome[Any]) -> None:
        i, job = jobs[j]
        if outcome.ok and isinstance(outcome.value, BagResult):
            store.put(job.key, outcome.value.record, outcome.value.arrays)
            settle(i, BagOutcome(job.bag, DONE, job.key))
        else:
            settle(i, BagOutcome(job.bag, FAILED, job.key, outcome.error or "no result"))

    executor.run(task, [job for _, job in jobs], on_done, keep_values=False)
    return [result[i] for i in range(len(bags))]
