"""RoadBEV-ROS: road surface elevation in bird's-eye view from stereo cameras, for ROS 2 Jazzy.

An ament_python-compatible package: ``colcon build`` installs it into a ROS 2 workspace, and
``pip install -e .`` into a plain virtual environment (see the README).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "roadbev_ros"
ROOT = Path(__file__).resolve().parent


def _version() -> str:
    """package.xml's version: one number for ROS (colcon, rosdep) and pip (``roadbev --version``)."""
    found = re.search(r"<version>([^<]+)</version>", (ROOT / "package.xml").read_text())
    if found is None:
        raise RuntimeError("package.xml has no <version>")
    return found.group(1).strip()


def _data_files() -> list[tuple[str, Sequence[str]]]:
    files: list[tuple[str, Sequence[str]]] = [
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ]
    for folder in ("launch", "config", "checkpoints"):  # checkpoints: the learned backends' defaults
        paths = sorted(str(p.relative_to(ROOT)) for p in (ROOT / folder).glob("*") if p.is_file())
        if paths:
            files.append((f"share/{PACKAGE}/{folder}", paths))
    return files


setup(
    name=PACKAGE,
    version=_version(),
    description="RoadBEV road surface elevation maps from stereo cameras and an IMU, for ROS 2",
    license="MIT",
    python_requires=">=3.10",
    packages=find_packages(include=["roadbev_core*", "msg_bridge*", "roadbev_ros*", "roadbev_lab*", "roadbev_cli*"]),
    # py.typed (PEP 561): the packages' annotations are their public types
    package_data={
        "roadbev_core": ["data/*", "py.typed"],
        "msg_bridge": ["py.typed"],
        "roadbev_ros": ["py.typed"],
        "roadbev_lab": ["py.typed"],
        "roadbev_cli": ["py.typed"],
    },
    data_files=_data_files(),
    install_requires=["numpy", "torch", "opencv-python-headless", "mcap", "rosbags", "pyyaml"],
    # the learned backends' ONNX runtimes (`roadbev export --format onnx`, `runtime: ...`)
    extras_require={
        "onnx": ["onnx>=1.16", "onnxruntime>=1.18"],
        "openvino": ["onnx>=1.16", "openvino>=2024.0"],
        # many bags on a Ray cluster (`roadbev eval/label --ray ADDRESS`); the car's install has no need of it
        "fleet": ["ray[default]>=2.9"],
    },
    zip_safe=False,
    entry_points={
        "console_scripts": [
            "roadbev = roadbev_cli.cli:main",
            "roadbev_node = roadbev_ros.node:main",
            "roadbev_preview_controller = roadbev_ros.preview_controller:main",
            "roadbev_hazard_monitor = roadbev_ros.hazard_monitor:main",
        ],
        # the built-in backends, found by name like any plugin's (roadbev_core.backend_plugins, which
        # also knows them without this metadata: BUILTIN_BACKENDS, checked equal by a test)
        "roadbev.backends": [
            "bev_sweep = roadbev_core.backends.bev_sweep:create_bev_sweep",
            "bm = roadbev_core.backends.image_view:create_bm",
            "sgbm = roadbev_core.backends.image_view:create_sgbm",
            "ensemble = roadbev_core.backends.ensemble:create_ensemble",
            "stereo = roadbev_core.backends.learned:create_stereo",
            "mono = roadbev_core.backends.learned:create_mono",
            "gwcnet = roadbev_core.backends.gwcnet:create_gwcnet",
            "adabins = roadbev_core.backends.adabins:create_adabins",
        ],
    },
)
