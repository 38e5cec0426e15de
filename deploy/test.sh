#!/usr/bin/env bash
# The whole test suite, set-up and build included. Safe to run again.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
bash deploy/setup.sh
# The end-to-end tests start the real binaries: build them first, in the tests' profile.
cargo build --release --workspace --locked
cargo test --release --workspace --locked --no-fail-fast "$@"
