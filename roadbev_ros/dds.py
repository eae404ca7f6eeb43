"""The Fast DDS profile that lets large images through, and the environment that selects it.

Fast DDS' default shared-memory transport has 512 KB segments and loses most 960x540 images
(docs/tutorials/your_car.md, "DDS"); ``config/fastdds.xml`` gives it a 64 MB segment plus UDPv4.
Fast DDS reads the profile named by ``FASTRTPS_DEFAULT_PROFILES_FILE`` (``FASTDDS_...`` in newer
releases) when the first participant is created, so :func:`use_profile` must run before
``rclpy.init``; node, replay, record and the tests all call it. A profile the user already chose
in the environment is respected.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable, Mapping, MutableMapping, Sequence
from pathlib import Path
from typing import Any

from roadbev_core.errors import RoadbevError
from roadbev_core.share import shared_candidates

__all__ = [
    "PROFILE_ENV_VARS",
    "DdsError",
    "child_env",
    "init_ros",
    "message_class",
    "profile_path",
    "spin_until_shutdown",
    "use_profile",
]

PROFILE_ENV_VARS: tuple[str, ...] = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
PROFILE_NAME = "fastdds.xml"


class DdsError(RoadbevError, RuntimeError):
    """The shipped DDS profile cannot be found."""


def _candidates() -> list[Path]:
    return shared_candidates(f"config/{PROFILE_NAME}")


def profile_path() -> Path:
    """The shipped ``fastdds.xml`` (source tree, venv prefix or an ament prefix).

    Raises:
        DdsError: not found anywhere.
    """
    for path in _candidates():
        if path.is_file():
            return path
    raise DdsError(f"{PROFILE_NAME} not found (looked in {', '.join(str(p) for p in _candidates())})")


def _uses_fastdds(env: Mapping[str, str]) -> bool:
    return env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp").startswith("rmw_fastrtps")


def use_profile(env: MutableMapping[str, str] | None = None) -> Path | None:
    """Point Fast DDS at the shipped profile unless the environment already names one.

    Args:
        env: the environment to change (``os.environ`` when None).

    Returns:
        The profile now in effect (the user's or ours), or None when another RMW is selected.
    """
    env = os.environ if env is None else env
    if not _uses_fastdds(env):
        return None
    for var in PROFILE_ENV_VARS:
        if env.get(var):
            chosen = Path(env[var])
            break
    else:
        chosen = profile_path()
    for var in PROFILE_ENV_VARS:
        env.setdefault(var, str(chosen))
    return chosen


def child_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """A copy of ``os.environ`` for a ROS subprocess, with the profile and ``extra`` applied."""
    env = dict(os.environ)
    env.update(extra or {})
    use_profile(env)
    return env


def message_class(msgtype: str) -> Any:
    """The rclpy message class of a ROS type name (``sensor_msgs/msg/Image`` or ``sensor_msgs/Image``).

    Raises:
        DdsError: the type's Python package is not installed (e.g. interfaces not built).
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise DdsError(f"not a ROS message type name: {msgtype!r}")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise DdsError(f"message type {msgtype} is not available in this environment") from None


def init_ros(args: list[str] | None = None, *, handle_signals: bool = True) -> Any:
    """Apply the DDS profile, then ``rclpy.init``; returns the rclpy module.

    Args:
        args: command-line arguments for rclpy (``--ros-args ...``); None = no arguments.
        handle_signals: keep rclpy's own SIGINT/SIGTERM handling (False for tools that must run
            their own shutdown, like the recorder closing its file).
    """
    use_profile()
    # lazy: rclpy loads after ROS_DOMAIN_ID and the DDS profile are set (child_env, the demo's private domain)
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    options = SignalHandlerOptions.ALL if handle_signals else SignalHandlerOptions.NO
    if not rclpy.ok():
        rclpy.init(args=args, signal_handler_options=options)
    return rclpy


def raise_interrupt(signum: int, _frame: object) -> None:
    """A signal handler for processes that run their own shutdown (``init_ros(handle_signals=False)``):
    the signal becomes a KeyboardInterrupt in the main thread's spin or wait."""
    raise KeyboardInterrupt(f"signal {signum}")


def spin_until_shutdown(rclpy: Any, node: Any, on_exit: Callable[[], None] | None = None) -> None:
    """Spin ``node`` on a single-threaded executor until Ctrl-C, SIGTERM or a shutdown; then run
    ``on_exit`` (e.g. stop a worker thread), destroy the node and shut rclpy down."""
    # lazy: as rclpy above
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if on_exit is not None:
            on_exit()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def asks_for_help(argv: Sequence[str]) -> bool:
    """``-h`` / ``--help`` among a node executable's own arguments (``argv[0]`` is the program;
    what follows ``--ros-args`` is rclpy's)."""
    own = list(argv[1:])
    if "--ros-args" in own:
        own = own[:own.index("--ros-args")]
    return any(arg in ("-h", "--help") for arg in own)


def node_usage(program: str, summary: str, defaults: Mapping[str, Any]) -> str:
    """The ``--help`` of a small node: how to pass parameters, and each with its default."""
    width = max(len(name) for name in defaults)
    lines = [f"usage: {program} [-h] [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO ...]", "",
             summary, "", "parameters (defaults):"]
    lines += [f"  {name:<{width}}  {value!r}" for name, value in defaults.items()]
    return "\n".join(lines)


def run_node(make_node: Callable[[], Any], program: str, refused: tuple[type[BaseException], ...],
             args: list[str] | None = None, *, usage: str = "") -> int:
    """A small node's ``main``: init rclpy with ``args`` (default ``sys.argv``), build the node,
    spin it until Ctrl-C / SIGTERM. Returns 0 (also after printing ``usage`` for ``-h`` /
    ``--help``, without starting anything), or 2 when building it raised one of ``refused`` (bad
    parameters: the reason goes to stderr as ``<program>: error: <reason>``)."""
    argv = list(sys.argv if args is None else args)
    if asks_for_help(argv):
        print(usage or f"usage: {program} [--ros-args ...]")
        return 0
    rclpy = init_ros(argv)
    try:
        node = make_node()
    except refused as exc:
        print(f"{program}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    spin_until_shutdown(rclpy, node)
    return 0

