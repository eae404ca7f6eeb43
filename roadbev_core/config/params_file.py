"""ROS 2 params YAML files and ``NAME=VALUE`` command-line items -> flat parameter dictionaries.

One reader for every entry point (``roadbev node --params``, ``roadbev eval --params``, the demo,
the online evaluation, the benchmarks). Values are then checked by
:meth:`roadbev_core.config.RoadbevConfig.from_params`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roadbev_core.config.grid import ConfigError

__all__ = ["NODE_NAME", "ParamError", "ParamsFile", "load_params_file", "parse_assignments"]

NODE_NAME = "roadbev"


class ParamError(ConfigError):
    """A parameter file, name or value that cannot be used, with the parameter's name."""


@dataclass(frozen=True)
class ParamsFile:
    """What a params YAML holds for one node.

    Attributes:
        values: parameter name -> value for the node (``/**`` first, then the node's section).
        other_sections: sections for other node names (not applied; worth a word to the user).
    """

    values: dict[str, Any]
    other_sections: tuple[str, ...] = field(default=())

    def note(self) -> str | None:
        """A sentence about the sections that were not applied (None when there are none)."""
        if not self.other_sections:
            return None
        return f"params file sections for other nodes not applied: {', '.join(self.other_sections)}"


def _node_keys(node_name: str) -> list[str]:
    """Keys a params YAML may use for ``node_name`` (with or without the leading slash)."""
    bare = node_name.lstrip("/")
    return [bare, f"/{bare}"]


def load_params_file(path: str | Path, node_name: str = NODE_NAME) -> ParamsFile:
    """Parameters for ``node_name`` from a standard ROS 2 params YAML.

    The ``/**`` wildcard section is merged first, then the node's own section (``roadbev:`` or
    ``/roadbev:``), so the node's values win. Nested parameter dictionaries are flattened with
    dots, like ROS 2 does (``preview: {tyre_width_m: 0.2}`` -> ``preview.tyre_width_m``).

    Args:
        path: the YAML file.
        node_name: the node whose section to read (a namespaced name ``/ns/roadbev`` matches
            ``/ns/roadbev`` and ``roadbev`` sections).

    Raises:
        ParamError: the file is missing, not YAML, not shaped like a params file, or it has
            sections but none for this node or ``/**`` (nothing in it would apply).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParamError(f"cannot read params file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ParamError(f"params file {path} is not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        flat = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise ParamError(f"params file {path} is not valid YAML: {flat}") from None
    if data is None:
        return ParamsFile({})
    if not isinstance(data, dict):
        raise ParamError(f"params file {path} must map node names to sections, got {type(data).__name__}")
    sections: list[str] = ["/**"]
    short = node_name.rstrip("/").rsplit("/", 1)[-1]
    for key in _node_keys(short) + _node_keys(node_name):
        if key not in sections:
            sections.append(key)
    merged: dict[str, Any] = {}
    for key in sections:
        if key not in data:
            continue
        section = data[key]
        if not isinstance(section, dict) or "ros__parameters" not in section:
            raise ParamError(f"params file {path}: section {key!r} lacks 'ros__parameters'")
        params = section["ros__parameters"]
        if params is None:
            continue
        if not isinstance(params, dict):
            raise ParamError(f"params file {path}: {key!r} ros__parameters must be a mapping")
        merged.update(_flatten(params))
    others = tuple(sorted(str(k) for k in data if k not in sections))
    if others and not any(key in data for key in sections):
        raise ParamError(
            f"params file {path} has no section for node {node_name!r} (or '/**'); its sections are "
            f"for {', '.join(others)}"
        )
    return ParamsFile(merged, others)


def parse_assignments(items: Iterable[str], option: str) -> dict[str, Any]:
    """Command-line ``NAME=VALUE`` items -> ``{NAME: value}``; values read as JSON (2, 0.5, true), else text.

    Raises:
        ParamError: an item without ``=`` or a name, naming the command-line ``option``.
    """
    parsed: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ParamError(f"{option} takes NAME=VALUE, got {item!r}")
        try:
            parsed[name.strip()] = json.loads(text)
        except json.JSONDecodeError:
            parsed[name.strip()] = text
    return parsed


def split_backend_spec(spec: str, option: str = "backend") -> tuple[str, dict[str, Any]]:
    """A backend with options, ``NAME[:OPTION=VALUE,...]`` (``bm:plane_parallax_px=16``) -> its
    name and options (values as :func:`parse_assignments` reads them). The options start after
    the first ``:`` that is followed by ``OPTION=`` (a ``=`` before any further ``:``): a plugin's
    ``module:attr`` path is a name, and an option's value may itself be a spec
    (``ensemble:pace_backend=bm:plane_parallax_px=16``).

    Raises:
        ParamError: an option without ``=``, naming ``option`` (what the spec was given as).
    """
    start = spec.find(":")
    while start >= 0:
        rest = spec[start + 1:]
        if "=" in rest.split(":", 1)[0]:
            return spec[:start].strip(), parse_assignments([i for i in rest.split(",") if i.strip()], option)
        start = spec.find(":", start + 1)
    return spec.strip(), {}


def _flatten(params: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in params.items():
        full = f"{prefix}{name}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{full}."))
        else:
            out[full] = value
    return out
