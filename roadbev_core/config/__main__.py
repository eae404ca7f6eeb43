"""``python -m roadbev_core.config``: print the shipped params file (config/roadbev.params.yaml)."""

from roadbev_core.config.tree import params_yaml

print(params_yaml(), end="")
