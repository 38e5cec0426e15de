#!/usr/bin/env bash
# Python packages the tests read the outputs back with (not needed to train): TensorBoard's own
# event reader, installed once into the per-user cache beside libtorch. Safe to run again.
set -euo pipefail
tensorboard_version=2.21.0
cache=${SELKD_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/selkd}
target="$cache/tensorboard-$tensorboard_version"
if [ ! -f "$target/.complete" ]; then
  echo "test-deps: installing tensorboard==$tensorboard_version into $target (one time)" >&2
  rm -rf "$target.partial"
  python3 -m pip install --quiet --disable-pip-version-check --no-warn-script-location \
    --target "$target.partial" "tensorboard==$tensorboard_version"
  rm -rf "$target"
  mv "$target.partial" "$target"
  touch "$target/.complete"
fi
echo "test-deps: tensorboard ready at $target" >&2
