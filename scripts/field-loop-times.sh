#!/usr/bin/env bash
# Times the host steps of the field loop (docs/field-guide.md) on a small recording set: four
# eagle-shoal trials replayed through the firmware with the samples stream on (the stand-in
# for a board: `slipguard replay --samples`), recorded by `slipguard monitor --capture …
# --record`, labelled, trained (hidden 8 by default, HIDDEN/EPOCHS to change), exported and
# checked with `slipguard-export inspect`. Prints one `step seconds` line per step.
# Env: PROFILE=release|debug (default release), KEEP_DIR=1 keeps the files.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
profile="${PROFILE:-release}"
hidden="${HIDDEN:-8}"
epochs="${EPOCHS:-2}"
work="$(mktemp -d)"
if [ "${KEEP_DIR:-0}" != 1 ]; then trap 'rm -rf "$work"' EXIT; else echo "field-loop-times: files in $work"; fi
flag=""
[ "$profile" = release ] && flag="--release"
(cd "$root" && cargo build -q $flag -p slipguard --bin slipguard -p slipguard-export --bin slipguard-export)
bin="${CARGO_TARGET_DIR:-$root/target}/$profile"

t() { # name, command…
  local name="$1"; shift
  local s; s=$(date +%s.%N)
  "$@" >"$work/$name.log" 2>&1 || { cat "$work/$name.log"; exit 1; }
  printf '%-8s %6.2f s\n' "$name" "$(echo "$(date +%s.%N) - $s" | bc)"
}

record_all() {
  mkdir -p "$work/rec"
  for id in Cheez_100_814_top_3 Scrub_100_461_right_5 Cheez_100_432_right_5 Cola_50_26_back_9; do
    "$bin/slipguard" replay "$root/data/eagle-shoal/trials/$id" --samples --script marks \
      --release-at "$(python3 -c "import json;print(json.load(open('$root/data/eagle-shoal/trials/$id/meta.json'))['label'][2])")" \
      --out "$work/$id.bin"
    "$bin/slipguard" monitor --capture "$work/$id.bin" --record "$work/rec/$id.csv" --view none
  done
}

t record record_all
t label "$bin/slipguard" label "$work/rec" --outcome-from-drop --out "$work/labelled"
t train "$bin/slipguard" train "$work/labelled" --out "$work/model" --variant lstm \
  --hidden "$hidden" --epochs "$epochs" --val-share 0.25 --name field
t export "$bin/slipguard-export" export "$work/model/field.safetensors" --data "$work/labelled" \
  -o "$work/model.bin"
t inspect "$bin/slipguard-export" inspect "$work/model.bin"
t eval "$bin/slipguard" eval "$work/model/field.safetensors" --data "$work/labelled" \
  --sim-force 0 --sim-suction 0
echo "field-loop-times: $(ls "$work/rec" | wc -l) recordings, $(cat "$work"/rec/*.csv | grep -vc '^[#t]') rows; blob $(stat -c %s "$work/model.bin") bytes"
