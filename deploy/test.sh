#!/usr/bin/env bash
# The whole test suite, set-up and build included. Safe to run again.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
# Which CPU ran the suite: a few tests read the machine (the products' libraries, timings).
echo "test: $(lscpu 2>/dev/null | sed -n 's/^Model name: *//p'), $(nproc) cores (cgroup cpu.max: $(cat /sys/fs/cgroup/cpu.max 2>/dev/null || echo none)), $(grep -o -w 'avx512f\|avx2\|fma' /proc/cpuinfo 2>/dev/null | sort -u | tr '\n' ' ')"
bash deploy/setup.sh
bash deploy/test-deps.sh
# The selkd Python package and its venv (tests/tests/python.rs runs its pytest files there).
bash deploy/python.sh
# Slurm and munge for tests/tests/slurm.rs (Debian's packages; needs root: elsewhere that test
# says it is skipped).
bash deploy/slurm.sh install || echo "test: Slurm could not be installed; tests/tests/slurm.rs will be skipped" >&2
# The end-to-end tests start the real binaries: build them first, in the tests' profile.
cargo build --release --workspace --locked
log=$(mktemp)
trap 'rm -f "$log"' EXIT
status=0
cargo test --release --workspace --locked --no-fail-fast "$@" 2>&1 | tee "$log" || status=$?
# One closing line for the whole suite (cargo's own last line is that of an empty doc-test run).
awk '/^test result:/ { for (i = 1; i <= NF; i++) { if ($i ~ /^passed/) p += $(i-1); if ($i ~ /^failed/) f += $(i-1) } }
     END { printf "%d passed, %d failed\n", p, f }' "$log"
exit "$status"
