#!/usr/bin/env bash
# Installs the pinned cargo-mutants into the project's cache (once, a few minutes) and prints the
# directory holding its binary, for deploy/mutants.sh and deploy/mutants-e2e.sh:
#   PATH="$(bash deploy/cargo-mutants.sh):$PATH" cargo mutants ...
set -euo pipefail
version=27.1.0
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
tool="$cache/cargo-mutants-$version"
if [ ! -x "$tool/bin/cargo-mutants" ]; then
  echo "cargo-mutants: installing $version into $tool (one time, a few minutes)" >&2
  cargo install --locked cargo-mutants --version "$version" --root "$tool" >&2
fi
echo "$tool/bin"
