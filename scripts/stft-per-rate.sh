#!/usr/bin/env bash
# STFT set-up per rate (docs/model-format.md, "STFT per rate"): the paper's 20-sample window
# (same samples) against a 48-sample one (1.2 s at 40 Hz, the paper's seconds; 0.68 s at 71 Hz,
# the longest window the core takes), bins 1..=10 in both, for a small stft-lstm (hidden 16,
# 6 epochs, 60 simulated training trials) at 40 Hz (hand) and 71 Hz (suction), seeds 1 to 3,
# scored by `eval` on 40 / 20 unseen simulated recordings (seed 99). Prints one line per run.
# Env: OUT (default: a temporary folder), RAYON_NUM_THREADS (default 1).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${OUT:-$(mktemp -d)}"
export RAYON_NUM_THREADS="${RAYON_NUM_THREADS:-1}"
(cd "$root" && cargo build -q --release -p slipguard)
S="${CARGO_TARGET_DIR:-$root/target}/release/slipguard"
cd "$out"
$S simulate --rate 40 --count 40 --seed 99 --failure-share 0.3 --out test40 >/dev/null
$S simulate --sensor suction --count 20 --seed 99 --failure-share 0.3 --out test71 >/dev/null
for seed in 1 2 3; do
  for n in 20 48; do
    for s in force suction; do
      if [ "$s" = force ]; then rate=(--rate-hz 40); test=test40; else rate=(--sensor suction); test=test71; fi
      name="$s-n$n-seed$seed"
      $S train "${rate[@]}" --variant stft-lstm --hidden 16 --epochs 6 --batch 64 --sim-mix 60 \
        --stft-window "$n" --seed "$seed" --out "$name" --name "$name" >"$name.log" 2>&1
      $S eval "$name/$name.safetensors" --data "$test" --sim-force 0 --sim-suction 0 >"$name.eval" 2>&1
      echo "$name $(grep -E '\| hand \|' "$name.eval" | head -1)"
    done
  done
done
