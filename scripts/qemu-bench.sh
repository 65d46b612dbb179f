#!/usr/bin/env bash
# Builds firmware/qemu-bench (a member of the firmware workspace) in release and runs it under QEMU (mps2-an386, -icount shift=0) with
# a timeout; exits with the bench's own status (0 ok, 1 check mismatch, 101 panic, 124 timeout).
# Works from any directory. Extra arguments go to cargo, e.g. `--features wrap-check`.
# Env: QEMU_BENCH_TIMEOUT (seconds, default 300).
set -euo pipefail

bench_dir="$(cd "$(dirname "${BASH_SOURCE[0]}")/../firmware/qemu-bench" && pwd)"
timeout_s="${QEMU_BENCH_TIMEOUT:-300}"
cd "$bench_dir"

cargo build --release "$@"
# The runner (firmware/cargo-runner.sh: qemu-system-arm … for slipguard-qemu-* ELFs) comes from
# firmware/.cargo/config.toml; the build above is done, so the timeout only covers QEMU. No
# stdin: QEMU's -nographic monitor stays idle.
status=0
timeout --kill-after=10 "$timeout_s" cargo run --release -q "$@" </dev/null || status=$?
if [ "$status" -eq 124 ]; then
  echo "qemu-bench: timed out after ${timeout_s} s" >&2
elif [ "$status" -ne 0 ]; then
  echo "qemu-bench: failed with exit status $status" >&2
fi
exit "$status"
