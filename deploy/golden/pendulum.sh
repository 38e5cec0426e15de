#!/usr/bin/env bash
# Regenerates envs/testdata/pendulum_v1.jsonl from Gymnasium 1.4.0 under NumPy 2, in a throwaway
# venv (deleted afterwards). See envs/testdata/README.md.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
venv=$(mktemp -d)
trap 'rm -rf "$venv"' EXIT
python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check "gymnasium==1.4.0" "numpy==2.4.6"
"$venv/bin/python" "$root/deploy/golden/pendulum.py" "$root/envs/testdata/pendulum_v1.jsonl"
echo "wrote $root/envs/testdata/pendulum_v1.jsonl" >&2
