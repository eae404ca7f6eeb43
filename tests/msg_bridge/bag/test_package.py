"""The package: each public name exported from the module that owns it, the same objects as
``msg_bridge``'s, and no bag library loaded by ``import msg_bridge``."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import msg_bridge
from msg_bridge import bag

REPO = Path(__file__).resolve().parents[3]
OWNERS = {
    "errors": {"BagError", "DamagedBagError"},
    "typestore": {"CUSTOM_PACKAGES", "deserialize", "serialize", "typestore"},
    "writer": {"COMPRESSIONS", "DEFAULT_CHUNK_SIZE", "BagWriter"},
    "metadata": {"MARKER_SUFFIX", "marker_path"},
    "reader": {"BagMessage", "OnDamage", "TopicInfo", "bag_topics", "read_messages"},
    "damage": {"ReadStats"},
    "info": {"BagInfo", "bag_info"},
    "recovery": {"recover_bag"},
}


def test_every_public_name_comes_from_the_module_that_owns_it() -> None:
    assert sorted(bag.__all__) == sorted(set().union(*OWNERS.values()))
    for module_name, names in OWNERS.items():
        module = importlib.import_module(f"msg_bridge.bag.{module_name}")
        for name in names:
            assert name in module.__all__, f"{name} not in msg_bridge.bag.{module_name}.__all__"
            assert getattr(bag, name) is getattr(module, name)


def test_the_docstring_names_every_module() -> None:
    assert bag.__doc__ is not None
    modules = sorted(p.stem for p in Path(bag.__file__).parent.glob("*.py") if p.stem != "__init__")
    assert modules == sorted([*OWNERS, "files", "mcap_file"])
    for module_name in modules:
        assert f":mod:`~msg_bridge.bag.{module_name}`" in bag.__doc__


def test_msg_bridge_re_exports_the_same_objects() -> None:
    shared = [n for n in msg_bridge.__all__ if n in bag.__all__]
    assert {"BagError", "BagWriter", "ReadStats", "read_messages", "recover_bag", "typestore"} <= set(shared)
    for name in shared:
        assert getattr(msg_bridge, name) is getattr(bag, name)


def test_importing_msg_bridge_loads_no_bag_library() -> None:
    """rosbags, mcap and yaml are imported on first use: the node imports msg_bridge at start-up."""
    code = ("import sys, msg_bridge.bag; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'rosbags', 'mcap', 'yaml'}))")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=os.environ.copy(), capture_output=True,
                          text=True, check=True, timeout=60)
    assert done.stdout.strip() == "[]"
