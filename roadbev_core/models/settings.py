"""The networks' configurations as checkpoints store them: a dict of their fields, read back
strictly (an unknown field is refused by name, never dropped)."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any, ClassVar, TypeVar, cast

from roadbev_core.config import ConfigError

__all__ = ["StoredSettings"]

_Settings = TypeVar("_Settings", bound="StoredSettings")


class StoredSettings:
    """Mixin for a frozen dataclass of a network's settings; ``SETTINGS`` names them in errors."""

    SETTINGS: ClassVar[str] = "model"

    def to_dict(self) -> dict[str, Any]:
        return asdict(cast(Any, self))  # a dataclass, as every subclass is

    @classmethod
    def from_dict(cls: type[_Settings], data: dict[str, Any]) -> _Settings:
        """The settings ``data`` holds (``to_dict``'s form).

        Raises:
            ConfigError: a field this configuration does not have, or a value its checks refuse.
        """
        unknown = set(data) - set(cls.__dataclass_fields__)  # type: ignore[attr-defined]
        if unknown:
            raise ConfigError(f"unknown {cls.SETTINGS} setting(s): {', '.join(sorted(unknown))}")
        return cls(**data)
