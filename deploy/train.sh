#!/usr/bin/env bash
# Set up, build, and train: `deploy/train.sh [selkd train options]`. Safe to run again.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash deploy/setup.sh
cargo build --release --workspace --locked --quiet
exec target/release/selkd train "$@"
