"""What describes a bag beside its MCAP records: rosbag2's ``metadata.yaml`` and the QoS profiles
of its channels (format 9, as ``ros2 bag`` writes them), and the ``.recording`` marker that lies
next to a bag while its writer is open.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from msg_bridge.bag.errors import BagError

__all__ = ["MARKER_SUFFIX", "marker_path", "qos_list", "qos_text", "read_metadata", "to_yaml"]

MARKER_SUFFIX = ".recording"


def marker_path(path: str | os.PathLike[str]) -> Path:
    """The ``<bag>.recording`` marker that lies next to a bag while its writer is open."""
    path = Path(path)
    return path.with_name(path.name + MARKER_SUFFIX)


def _qos(latched: bool) -> list[Any]:
    # Imported on use: rosbags is slow to import and ``import msg_bridge`` writes no bag.
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    durability = QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE
    zero = QosTime(0, 0)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            1 if latched else 10,
            QosReliability.RELIABLE,
            durability,
            zero,
            zero,
            QosLiveliness.AUTOMATIC,
            zero,
            False,
        )
    ]


def qos_text(latched: bool) -> str:
    """``offered_qos_profiles`` as rosbag2 (format 9) stores it in the channel metadata."""
    # Imported on use: yaml and rosbags are slow to import and ``import msg_bridge`` writes no bag.
    import yaml
    from rosbags.rosbag2.metadata import dump_qos_v9

    return yaml.safe_dump(dump_qos_v9(_qos(latched)), default_flow_style=False, sort_keys=False).strip()


def qos_list(text: str) -> Any:
    """The QoS profiles of a channel's ``offered_qos_profiles`` text; [] when there is none or it
    is no YAML."""
    import yaml  # imported on use, as above

    try:
        return yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []


def to_yaml(value: Any) -> str:
    """``value`` as the YAML of ``metadata.yaml`` (keys in their order, block style)."""
    import yaml  # imported on use, as above

    return yaml.safe_dump(value, default_flow_style=False, sort_keys=False)


def read_metadata(path: Path) -> dict[str, Any] | None:
    """The ``rosbag2_bagfile_information`` of a rosbag2 directory; None without ``metadata.yaml``.

    Raises:
        BagError: ``metadata.yaml`` is not UTF-8 text or not a rosbag2 metadata file (one line).
    """
    import yaml  # imported on use, as above

    meta = path / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
    except UnicodeDecodeError as exc:
        raise BagError(f"{meta}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        flat = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise BagError(f"{meta}: not a rosbag2 metadata file ({flat})") from None
    if not isinstance(info, dict):
        raise BagError(f"{meta}: not a rosbag2 metadata file")
    return info
