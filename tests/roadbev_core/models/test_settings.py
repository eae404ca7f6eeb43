"""A network's settings round-trip through a checkpoint's dict and unknown fields are refused."""

from __future__ import annotations

import pytest

from roadbev_core.config import ConfigError
from roadbev_core.models.adabins import AdaBinsConfig
from roadbev_core.models.gwcnet import GwcNetConfig
from roadbev_core.models.presets import ModelConfig, model_config


@pytest.mark.parametrize("config", [GwcNetConfig(groups=4, features=32), AdaBinsConfig(n_bins=32),
                                    model_config("lite", "mono")])
def test_settings_come_back_from_their_dict(config: GwcNetConfig | AdaBinsConfig | ModelConfig) -> None:
    assert type(config).from_dict(config.to_dict()) == config


@pytest.mark.parametrize("kind, name", [(GwcNetConfig, "GwcNet"), (AdaBinsConfig, "AdaBins"), (ModelConfig, "model")])
def test_an_unknown_setting_is_refused_by_name(kind: type[GwcNetConfig | AdaBinsConfig | ModelConfig],
                                               name: str) -> None:
    with pytest.raises(ConfigError, match=f"unknown {name} setting\\(s\\): bogus, extra"):
        kind.from_dict({"extra": 1, "bogus": 2})
