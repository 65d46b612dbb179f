#!/usr/bin/env bash
# Runs every cargo-fuzz target of fuzz/ for SECONDS each (default 20) from the seed corpus
# (fuzz/seed.sh) and fails on the first crash, leak or timeout; the crashing input is in
# fuzz/artifacts/<target>/. Installs the nightly toolchain and cargo-fuzz if they are missing.
# Longer runs: scripts/fuzz.sh 600, or one target: scripts/fuzz.sh 3600 blob.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../fuzz"
secs="${1:-20}"
shift || true
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(blob protocol app upload recording eagle import_safetensors import_onnx import_keras)

rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-target}-fuzz"

./seed.sh
cargo +nightly fuzz build -O
for t in "${targets[@]}"; do
  start=$SECONDS
  log=$(mktemp)
  if ! cargo +nightly fuzz run -O "$t" "corpus/$t" -- -max_total_time="$secs" -rss_limit_mb=2048 \
      -timeout=20 >"$log" 2>&1; then
    tail -n 40 "$log"
    echo "fuzz: $t found a crash (input in fuzz/artifacts/$t/)" >&2
    exit 1
  fi
  printf 'fuzz: %-20s %s (%d s)\n' "$t" "$(grep -oE 'Done [0-9]+ runs' "$log" | tail -n 1)" "$((SECONDS - start))"
  rm -f "$log"
done
