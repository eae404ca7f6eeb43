"""Backends found by name, without importing them: the names the config validates against.

A backend is made by a factory ``factory(grid, **options) -> Backend`` (the protocol of
:mod:`roadbev_core.backends`), named in the ``backend`` parameter by

* a built-in name (:data:`BUILTIN_BACKENDS`), known without any package metadata, so a tree
  that was never pip-installed (colcon, ``PYTHONPATH``) or an install whose metadata predates a
  backend still has them all;
* an entry point in the group :data:`ENTRY_POINT_GROUP` of any installed distribution, for
  example in a plugin's ``pyproject.toml``::

      [project.entry-points."roadbev.backends"]
      toy = "toy_backend:create"

* a ``module:attr`` path given as the name itself (``backend: toy_backend:create``), for a
  package importable without entry points (on ``PYTHONPATH``, or not pip-installed).

Options of a backend are the parameters ``<backend>.<option>`` (``toy.scale``,
``toy_backend:create.scale``); they reach its factory as keyword arguments. The ``checkpoint``
parameter goes to the built-in learned backends (:func:`takes_checkpoint`); a plugin that
reads a file takes it as its own option (``toy.checkpoint``).

Nothing here imports a backend: :meth:`BackendPlugin.load` does, when
:func:`roadbev_core.backends.create` builds one, so choosing ``bm`` never imports torch, and the
config checks names and options with this module alone. Entry points are read with
:func:`importlib.metadata.entry_points` once per ``sys.path`` (a package installed into a
running process is seen after a restart, or after :func:`forget_entry_points`).
"""

from __future__ import annotations

import importlib
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from importlib.metadata import entry_points
from typing import Any, cast

from roadbev_core.errors import RoadbevError

__all__ = [
    "BUILTIN_BACKENDS",
    "ENTRY_POINT_GROUP",
    "BackendError",
    "BackendPlugin",
    "available",
    "find",
    "forget_entry_points",
    "is_backend_name",
    "is_path",
    "option_backend",
    "takes_checkpoint",
]

ENTRY_POINT_GROUP = "roadbev.backends"
# name -> factory of the backends that ship with the package (setup.py declares the same entry
# points; tests/roadbev_core/test_backend_plugins.py checks they agree).
BUILTIN_BACKENDS: Mapping[str, str] = {
    "bev_sweep": "roadbev_core.backends.bev_sweep:create_bev_sweep",
    "bm": "roadbev_core.backends.image_view:create_bm",
    "sgbm": "roadbev_core.backends.image_view:create_sgbm",
    "ensemble": "roadbev_core.backends.ensemble:create_ensemble",
    "stereo": "roadbev_core.backends.learned:create_stereo",
    "mono": "roadbev_core.backends.learned:create_mono",
    "gwcnet": "roadbev_core.backends.gwcnet:create_gwcnet",
    "adabins": "roadbev_core.backends.adabins:create_adabins",
}
# Built-in backends whose networks come from a checkpoint (the `checkpoint` parameter applies to them).
_CHECKPOINT_BACKENDS = frozenset({"stereo", "mono", "gwcnet", "adabins"})
_BUILTIN_SOURCE = "built in"
# a dotted module, a colon, a dotted attribute: "pkg.module:factory"
_PATH = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


class BackendError(RoadbevError, RuntimeError):
    """A backend that cannot be created (unknown name, a plugin that does not load, missing
    checkpoint, bad option)."""


@dataclass(frozen=True)
class BackendPlugin:
    """Where a backend's factory is, without having imported it.

    Attributes:
        name: the backend's name, as given in the ``backend`` parameter.
        target: its factory, ``module:attr``.
        source: where the name comes from: ``built in``, the distribution declaring the entry
            point (``toy-backend 0.1``), or ``module:attr path``.
        conflict: another factory declared under the same name (``source: target``), or ''.
    """

    name: str
    target: str
    source: str
    conflict: str = ""

    def load(self) -> Callable[..., Any]:
        """Import the factory.

        Raises:
            BackendError: naming the plugin: two factories under one name, a module that fails
                to import (whatever it raised), a missing attribute, or one that is not callable.
        """
        if self.conflict:
            raise BackendError(f"backend {self.name!r} is declared twice: {self.source}: {self.target} and "
                               f"{self.conflict}; uninstall one of them")
        where = f"backend plugin {self.name!r} ({self.target}, {self.source})"
        module_name, _, attr = self.target.partition(":")
        try:
            obj: Any = importlib.import_module(module_name)
        except Exception as exc:  # a plugin's import error of any kind is a refusal with its name
            raise BackendError(f"{where} cannot be imported: {type(exc).__name__}: {exc}") from exc
        for part in attr.split(".") if attr else ():
            try:
                obj = getattr(obj, part)
            except AttributeError:
                raise BackendError(f"{where}: module {module_name} has no attribute {attr!r}") from None
        if not callable(obj):
            raise BackendError(f"{where} is {type(obj).__name__!r}, not a factory(grid, **options) -> Backend")
        return cast("Callable[..., Any]", obj)


def is_path(name: str) -> bool:
    """Whether ``name`` is a ``module:attr`` path (a backend named by where its factory is)."""
    return bool(_PATH.match(name))


def _option_without_value(name: str) -> str | None:
    """The backend of ``name`` when it reads as a path but is a known backend and an option with
    no value (``bm:plane_parallax_px``: ``NAME:OPTION=VALUE`` without its ``=VALUE``), else None."""
    head = name.partition(":")[0]
    return head if is_path(name) and head in _plugins() else None


@lru_cache(maxsize=4)
def _entry_points(path: tuple[str, ...]) -> dict[str, BackendPlugin]:
    """name -> plugin of the group's entry points on ``path`` (``sys.path``: the cache key)."""
    found: dict[str, BackendPlugin] = {}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        dist = point.dist
        source = f"{dist.name} {dist.version}" if dist is not None else "an entry point"
        target = f"{point.module}:{point.attr}" if point.attr else point.module
        plugin = BackendPlugin(point.name, target, source)
        seen = found.get(point.name)
        if seen is None:
            found[point.name] = plugin
        elif seen.target != target and not seen.conflict:  # the same one twice on the path is one
            found[point.name] = BackendPlugin(point.name, seen.target, seen.source, f"{source}: {target}")
    return found


def forget_entry_points() -> None:
    """Read the entry points again at the next look-up (a package was installed meanwhile)."""
    _entry_points.cache_clear()


def _plugins() -> dict[str, BackendPlugin]:
    """Every backend known by name: the built-in ones, then the entry points."""
    out = {name: BackendPlugin(name, target, _BUILTIN_SOURCE) for name, target in BUILTIN_BACKENDS.items()}
    for name, plugin in _entry_points(tuple(sys.path)).items():
        builtin = out.get(name)
        if builtin is None:
            out[name] = plugin
        elif plugin.target != builtin.target:  # the package's own entry points repeat the table
            out[name] = BackendPlugin(name, builtin.target, builtin.source, f"{plugin.source}: {plugin.target}")
    return out


def available() -> list[str]:
    """Names of all backends known by name (built in and entry points), sorted."""
    return sorted(_plugins())


def is_backend_name(name: str) -> bool:
    """Whether ``name`` names a backend: a known name or a ``module:attr`` path (not imported) whose
    module is not a known backend's name (that is an option without its value)."""
    return name in _plugins() or (is_path(name) and _option_without_value(name) is None)


def find(name: str) -> BackendPlugin:
    """The plugin behind ``name`` (nothing imported yet).

    Raises:
        BackendError: an unknown name, listing the known ones.
    """
    plugin = _plugins().get(name)
    if plugin is not None:
        return plugin
    backend = _option_without_value(name)
    if backend is not None:
        raise BackendError(f"{name!r} is backend {backend!r} with an option but no value: give it as "
                           f"{backend}:OPTION=VALUE")
    if is_path(name):
        return BackendPlugin(name, name, "module:attr path")
    raise BackendError(f"unknown backend {name!r}; choose from {', '.join(available())}")


def option_backend(parameter: str) -> str | None:
    """The backend of a parameter ``<backend>.<option>`` (a known name or a ``module:attr``
    path before the option), or None when ``parameter`` is not one."""
    if ":" in parameter:  # a path's module is dotted: the option is after the last dot
        head, dot, tail = parameter.rpartition(".")
        return head if dot and tail and is_path(head) else None
    head, dot, tail = parameter.partition(".")
    if not (dot and tail):
        return None
    return head if head in _plugins() else None


def takes_checkpoint(name: str) -> bool:
    """Whether backend ``name`` reads the ``checkpoint`` parameter (the built-in learned ones)."""
    return name in _CHECKPOINT_BACKENDS
