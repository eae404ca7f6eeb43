"""The package as a ROS 2 user gets it: package.xml names every dependency, and a colcon workspace
with this package and the two interface packages builds, and the node runs from its install space.

The workspace lives in ``.cache/roadbev/colcon_ws`` (source links into this checkout), so after the
first build (about 3 minutes here, most of it compiling the interfaces' type support) a rerun
is incremental. colcon comes from PyPI (``colcon-common-extensions`` in requirements.txt); the
build test is skipped only where colcon, cmake, ninja or a C++ compiler is missing.
"""

from __future__ import annotations

import ast
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("roadbev_core", "msg_bridge", "roadbev_ros")
# import name -> the package.xml key (or "pip:<name>" for what only pip has: the comment lists it)
PYTHON_DEPS = {
    "numpy": "python3-numpy", "cv2": "python3-opencv", "yaml": "python3-yaml", "matplotlib": "python3-matplotlib",
    "mpl_toolkits": "python3-matplotlib", "tqdm": "python3-tqdm", "torch": "python3-torch",
    "rosbags": "python3-rosbags-pip", "rclpy": "rclpy", "launch": "launch", "launch_ros": "launch_ros",
    "mcap": "pip:mcap", "zstandard": "pip:zstandard", "lz4": "pip:lz4", "onnx": "pip:onnx",
    "onnxruntime": "pip:onnxruntime", "openvino": "pip:openvino",
}
OWN = set(PACKAGES) | {"benchmarks", "tests"}


def imported_modules() -> set[str]:
    """Top-level modules imported anywhere in the three packages and the launch file."""
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")] + list((ROOT / "launch").glob("*.py"))
    found: set[str] = set()
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                found |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module.split(".")[0])
    return {m for m in found if m not in sys.stdlib_module_names and m not in OWN}


def test_package_xml_names_every_dependency() -> None:
    from catkin_pkg.package import parse_package  # type: ignore[import-untyped]

    package = parse_package(str(ROOT / "package.xml"))
    package.validate()
    keys = {d.name for d in package.exec_depends}
    text = (ROOT / "package.xml").read_text()
    pip_only = re.search(r"pip-only.*?-->", text, re.DOTALL)
    assert pip_only is not None, "package.xml lists no pip-only dependencies"
    missing = []
    for module in sorted(imported_modules()):
        key = PYTHON_DEPS.get(module, module)  # ROS packages (*_msgs, rcl_interfaces) are their own keys
        if key.startswith("pip:"):
            if not re.search(rf"^\s+{re.escape(key[4:])}\b", pip_only.group(0), re.MULTILINE):
                missing.append(f"{module} (pip-only {key[4:]})")
        elif key not in keys:
            missing.append(f"{module} ({key})")
    assert not missing, f"imported but not in package.xml: {missing}"
    for key in ("launch_ros", "python3-torch", "python3-rosbags-pip", "grid_map_msgs", "roadbev_msgs"):
        assert key in keys


def _tool(name: str) -> str | None:
    beside = Path(sys.executable).parent / name
    return str(beside) if beside.exists() else shutil.which(name)


MISSING = [t for t in ("colcon", "cmake", "ninja", "c++") if _tool(t) is None]


@pytest.mark.skipif(bool(MISSING), reason=f"not installed: {', '.join(MISSING)}")
def test_a_colcon_workspace_builds_and_the_node_starts_from_its_install_space(tmp_path: Path) -> None:
    ws = ROOT / ".cache" / "roadbev" / "colcon_ws"
    src = ws / "src"
    src.mkdir(parents=True, exist_ok=True)
    for name, target in (("roadbev_ros", ROOT), ("grid_map_msgs", ROOT / "interfaces" / "grid_map_msgs"),
                         ("roadbev_msgs", ROOT / "interfaces" / "roadbev_msgs")):
        link = src / name
        if link.is_symlink() and link.resolve() != target.resolve():
            link.unlink()  # a workspace made from another checkout
        if not link.is_symlink():
            link.symlink_to(target)
    prefix = sys.prefix
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH")}
    env.update(PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=prefix,
               CMAKE_PREFIX_PATH=prefix, AMENT_PREFIX_PATH=prefix)
    build = subprocess.run(
        [str(_tool("colcon")), "build", "--event-handlers", "console_direct-", "--cmake-args", "-G", "Ninja",
         f"-DCMAKE_PROJECT_INCLUDE={ROOT / 'scripts' / 'ros_wheels_fix.cmake'}",
         f"-DPython3_EXECUTABLE={sys.executable}", "-DBUILD_TESTING=OFF"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=1200)
    assert build.returncode == 0, build.stdout[-4000:] + build.stderr[-4000:]
    assert "3 packages finished" in build.stdout, build.stdout[-2000:]
    install = ws / "install"
    share = install / "roadbev_ros" / "share" / "roadbev_ros"
    for path in ("package.xml", "config/fastdds.xml", "config/roadbev.params.yaml", "launch/roadbev.launch.py",
                 "checkpoints/roadbev_stereo_lite.pt", "checkpoints/roadbev_mono_lite.pt"):
        assert (share / path).is_file(), path
    bin_dir = install / "roadbev_ros" / "lib" / "roadbev_ros"  # where `ros2 run roadbev_ros ...` looks
    # what a user does: source the workspace, then run the package's programs
    check = (f"source {install / 'setup.bash'} && "
             "python -c 'import roadbev_ros, msg_bridge, grid_map_msgs.msg, roadbev_msgs.msg; "
             "from roadbev_ros.dds import profile_path; print(roadbev_ros.__file__); print(profile_path()); "
             "from roadbev_core.backends.learned import default_checkpoint; print(default_checkpoint(\"stereo\"))' && "
             f"{bin_dir / 'roadbev'} --version && {bin_dir / 'roadbev'} node --help")
    # (from another folder: python -c puts the current one first on sys.path)
    run = subprocess.run(["bash", "-c", check], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    assert lines[0].startswith(str(install)), lines  # the install space's copy, not this checkout
    assert lines[1] == str(share / "config" / "fastdds.xml"), lines
    assert lines[2] == str(share / "checkpoints" / "roadbev_stereo_lite.pt"), lines  # -p backend:=stereo works
    assert lines[3].startswith("roadbev ") and "usage: roadbev node" in run.stdout
    # the node itself, from the install space, until it is up; then Ctrl-C
    log = tmp_path / "node.log"
    with log.open("wb") as out:
        node = subprocess.Popen(["bash", "-c", f"source {install / 'setup.bash'} && exec {bin_dir / 'roadbev_node'} "
                                 "--ros-args -p backend:=bm"], cwd=tmp_path, env=env, stdout=out,
                                stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and "backend bm" not in log.read_text() and node.poll() is None:
            time.sleep(0.2)
        assert "backend bm" in log.read_text(), log.read_text()
        assert str(install) in subprocess.run(["cat", f"/proc/{node.pid}/cmdline"], capture_output=True,
                                              text=True).stdout.replace("\0", " ")
    finally:
        node.send_signal(signal.SIGINT)
        try:
            code = node.wait(30)
        except subprocess.TimeoutExpired:
            node.kill()
            code = node.wait(10)
    assert code == 0, log.read_text()
