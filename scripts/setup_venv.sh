#!/usr/bin/env bash
# Creates ./.venv with everything the project needs, builds the interface packages into it and
# installs the project in editable mode. Idempotent: a stamp file records the inputs it was built
# from, so a second call with nothing changed returns at once.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/.venv"
stamp="$venv/.roadbev-setup"
inputs=$(cd "$root" && { find requirements.txt requirements-docs.txt setup.py scripts interfaces -type f 2>/dev/null || true; } \
  | sort | xargs cat | sha256sum | cut -d' ' -f1)
if [[ -f "$stamp" && "$(cat "$stamp")" == "$inputs" ]]; then
  exit 0
fi
echo "[setup] creating $venv (torch CPU, ROS 2 Jazzy wheels, interface packages, Sphinx)" >&2
python3 -m venv "$venv"
# This machine's pip.conf lists local find-links folders that may not exist; drop that noise.
quiet() { { grep -v 'is neither a file nor a directory' || true; } >&2; }
"$venv/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip setuptools wheel 2>&1 | quiet
"$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$root/requirements.txt" \
  -r "$root/requirements-docs.txt" 2>&1 | quiet
if [[ -x "$root/scripts/build_interfaces.sh" ]]; then
  "$root/scripts/build_interfaces.sh" "$venv"
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e "$root" 2>&1 | quiet
echo "$inputs" > "$stamp"
echo "[setup] done" >&2
