#!/usr/bin/env bash
# Byte-for-byte check of the emulated firmware against the host replay.
#
# 1. Builds firmware/qemu-app (the firmware application with the recorded-trial board layer) and
#    runs it under QEMU mps2-an386; it writes every frame it sends to qemu-frames.bin (semihosting).
# 2. Runs the host replay of the same trial and command script through the same portable logic
#    (`slipguard replay … --script cheez`, which wraps `slipguard_app::replay::run`).
# 3. Compares the two byte for byte; then repeats with a corrupted model blob loaded into the MODEL
#    region in place of the built-in one (as re-flashing sector 11 would), where both sides must
#    send fault frames and no flags.
# 4. Decodes the QEMU frames with the C decoder (host-tools/c).
# 5. The field script (qemu-app feature `field`): sample stream on, grasp start, lift, release,
#    an upload of the golden test model into a RAM-backed model slot while the frames go on,
#    grasp start on it; compared with the host side (`replay_field` example), then C-decoded.
# 6. The field loop at 40 Hz on the hand profile and at 71 Hz on the suction profile, end to
#    end: grasps written by `slipguard simulate`, recorded from the firmware's samples stream
#    (`replay --samples` through `monitor --record`), labelled (`label --outcome-from-drop`),
#    trained (tiny: LSTM hidden 4, one epoch, as host-tools/tests/rates.rs) and exported
#    (`slipguard-export export`). A scenario file (the first grasp, repeated, on the profile its
#    unit implies, and the exported blob; `field_scenario` example of host-tools) goes into the
#    QEMU build's SCENARIO region, the shipped model for the rate into the MODEL region; the
#    field script uploads the new blob. The frames equal the host replay's (`replay_field
#    --scenario`) byte for byte, and the host side checks that the flags after the upload are
#    the new model's (a run on it from boot) and not the old one's.
# Exit status 0 when every comparison matches, 1 on a mismatch, else the failing command's status.
# Works from any directory. Env: QEMU_REPLAY_TIMEOUT (seconds, default 300), KEEP_DIR=1 keeps the files.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
timeout_s="${QEMU_REPLAY_TIMEOUT:-300}"
work="$(mktemp -d)"
if [ "${KEEP_DIR:-0}" != 1 ]; then trap 'rm -rf "$work"' EXIT; else echo "qemu-replay: files in $work"; fi

(cd "$root/firmware" && cargo build --release -p slipguard-qemu-app)
elf="${CARGO_TARGET_DIR:-$root/firmware/target}/thumbv7em-none-eabihf/release/slipguard-qemu-app"
(cd "$root" && cargo build -q -p slipguard --bin slipguard)
slipguard="${CARGO_TARGET_DIR:-$root/target}/debug/slipguard"
trial="$root/firmware/app/fixtures/Cheez_100_814_top_3.csv"
golden="$root/firmware/core/tests/fixtures/bench/model.bin"
# The blob the build embeds, chosen by the same rule as firmware/support/build.rs.
if [ -n "${SLIPGUARD_MODEL:-}" ]; then
  case "$SLIPGUARD_MODEL" in /*) model="$SLIPGUARD_MODEL" ;; *) model="$root/$SLIPGUARD_MODEL" ;; esac
elif [ -f "$root/models/hand-force/hand-force.bin" ]; then
  model="$root/models/hand-force/hand-force.bin"
else
  model="$golden"
fi

qemu() { # qemu ELF [extra args…]: runs in $work, output file qemu-frames.bin
  local elf="$1"
  shift
  rm -f "$work/qemu-frames.bin"
  (cd "$work" && timeout --kill-after=10 "$timeout_s" qemu-system-arm -M mps2-an386 -nographic \
    -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off \
    -kernel "$elf" "$@" </dev/null)
}

compare() { # compare NAME HOST QEMU
  if cmp -s "$2" "$3"; then
    echo "qemu-replay: $1: QEMU build and host replay identical ($(wc -c <"$2") bytes)"
  else
    echo "qemu-replay: $1: MISMATCH between the host replay and the QEMU build" >&2
    cmp "$2" "$3" >&2 || true
    exit 1
  fi
}

# 1. The built-in model blob.
qemu "$elf"
mv "$work/qemu-frames.bin" "$work/qemu.bin"
"$slipguard" replay "$trial" --model "$model" --script cheez --out "$work/host.bin"
compare "built-in model $(basename "$model")" "$work/host.bin" "$work/qemu.bin"

# 2. A corrupted blob (one flipped bit inside a tensor) in the MODEL region.
python3 - "$model" "$work/corrupt.bin" <<'PY'
import sys
b = bytearray(open(sys.argv[1], 'rb').read())
b[len(b) // 2] ^= 0x10  # inside the tensors of any blob (the hand model is 3.7 kB)
open(sys.argv[2], 'wb').write(b)
PY
arm-none-eabi-objcopy --remove-section .model "$elf" "$work/no-model.elf" 2>/dev/null
qemu "$work/no-model.elf" -device "loader,file=$work/corrupt.bin,addr=0x00300000"
mv "$work/qemu-frames.bin" "$work/qemu-corrupt.bin"
"$slipguard" replay "$trial" --model "$work/corrupt.bin" --allow-bad-model --script cheez --out "$work/host-corrupt.bin"
# The host side must hold fault frames and not a single flag frame (the monitor counts them).
summary="$("$slipguard" monitor --capture "$work/host-corrupt.bin" --view none | tail -n 1)"
case "$summary" in
*" flags=0 faults=0 "*) echo "qemu-replay: corrupted blob: no fault frame ($summary)" >&2; exit 1 ;;
*" flags=0 "*) ;;
*) echo "qemu-replay: corrupted blob: flag frames sent ($summary)" >&2; exit 1 ;;
esac
compare "corrupted model blob" "$work/host-corrupt.bin" "$work/qemu-corrupt.bin"

# 3. The C decoder (host-tools/c/slipguard_protocol.h) on the QEMU build's frames: every run
#    decodes, and the stream holds the 400 flag frames of the trial.
cc -std=c99 -Wall -Wextra -Werror -pedantic -I "$root/host-tools/c" "$root/host-tools/c/test_decode.c" -o "$work/test_decode"
"$work/test_decode" <"$work/qemu.bin" >"$work/qemu-c.txt"
n_flags="$(grep -c '^flags' "$work/qemu-c.txt" || true)"
if grep -q '^bad' "$work/qemu-c.txt" || [ "$n_flags" != 400 ]; then
  echo "qemu-replay: C decoder on the QEMU frames: $n_flags flag frames, $(grep -c '^bad' "$work/qemu-c.txt" || true) bad runs" >&2
  exit 1
fi
echo "qemu-replay: C decoder: $(wc -l <"$work/qemu-c.txt") frames of the QEMU build decoded ($n_flags flag frames)"

# 5. The field script: sample stream, phase marks, an upload into the RAM-backed free slot, then
#    flags from the uploaded model.
(cd "$root/firmware" && cargo build --release -p slipguard-qemu-app --features field)
qemu "$elf"
mv "$work/qemu-frames.bin" "$work/qemu-field.bin"
(cd "$root" && cargo run -q -p slipguard-app --example replay_field -- "$model" "$golden") >"$work/host-field.bin"
compare "field script (samples, upload, new model)" "$work/host-field.bin" "$work/qemu-field.bin"
"$work/test_decode" <"$work/qemu-field.bin" >"$work/qemu-field-c.txt"
n_samples="$(grep -c '^samples' "$work/qemu-field-c.txt" || true)"
n_marks="$(grep -c '^samples.* marks=[1-7] ' "$work/qemu-field-c.txt" || true)"
if grep -q '^bad' "$work/qemu-field-c.txt" || [ "$n_samples" != 400 ] || [ "$n_marks" != 4 ]; then
  echo "qemu-replay: C decoder on the field frames: $n_samples samples frames, $n_marks marked" >&2
  exit 1
fi
echo "qemu-replay: C decoder: field script, $n_samples samples frames, $n_marks phase marks"

# 6. The field loop at 40 Hz (hand) and 71 Hz (suction): simulate → record → label → train →
#    export → upload on QEMU → flags from the new model, equal to the host replay.
(cd "$root" && cargo build -q -p slipguard-export --bin slipguard-export &&
  cargo build -q -p slipguard --example field_scenario && cargo build -q -p slipguard-app --example replay_field)
exporter="${CARGO_TARGET_DIR:-$root/target}/debug/slipguard-export"
scenario_tool="${CARGO_TARGET_DIR:-$root/target}/debug/examples/field_scenario"
replay_field="${CARGO_TARGET_DIR:-$root/target}/debug/examples/replay_field"
arm-none-eabi-objcopy --remove-section .model "$elf" "$work/field-no-model.elf" 2>/dev/null
field_loop() { # field_loop DIR NAME SIMULATE-ARGS…
  local d="$work/$1" name="$2"
  shift 2
  mkdir -p "$d/rec"
  local t0
  t0="$(date +%s%N)"
  quiet() { "$@" >>"$d/steps.log" 2>&1 || { cat "$d/steps.log" >&2; return 1; }; }
  quiet "$slipguard" simulate "$@" --failure-share 0.5 --out "$d/sim"
  local f id open
  for f in "$d"/sim/*.csv; do
    id="$(basename "$f" .csv)"
    open="$(sed -n 's/^# open_start: *//p' "$f" | tr -d ' \r')"
    quiet "$slipguard" replay "$f" --samples --script marks --release-at "$open" --out "$d/$id.bin"
    quiet "$slipguard" monitor --capture "$d/$id.bin" --record "$d/rec/$id.csv"
  done
  quiet "$slipguard" label "$d/rec" --outcome-from-drop --out "$d/labelled"
  quiet "$slipguard" train "$d/labelled" --out "$d/model" --variant lstm --hidden 4 --epochs 1 --batch 64 \
    --name field
  quiet "$exporter" export "$d/model/field.safetensors" --data "$d/labelled" --no-holdout --no-report --quiet \
    -o "$d/new.bin"
  local first old
  first="$(ls "$d"/sim/*.csv | sort | head -n 1)"
  old="$(cd "$root" && "$scenario_tool" "$first" "$d/new.bin" "$d/scenario.bin")"
  case "$old" in /*) ;; *) old="$root/$old" ;; esac
  qemu "$work/field-no-model.elf" -device "loader,file=$old,addr=0x00300000" \
    -device "loader,file=$d/scenario.bin,addr=0x21000000" | tee "$d/qemu.log"
  grep -q "scenario from 0x21000000" "$d/qemu.log" || { echo "qemu-replay: $name: the scenario was not read" >&2; exit 1; }
  grep -q "new model in slot" "$d/qemu.log" || { echo "qemu-replay: $name: no new model after the upload" >&2; exit 1; }
  mv "$work/qemu-frames.bin" "$d/qemu.bin"
  "$replay_field" --scenario "$d/scenario.bin" "$old" >"$d/host.bin"
  compare "field loop $name ($(basename "$old") → the exported blob)" "$d/host.bin" "$d/qemu.bin"
  echo "qemu-replay: field loop $name: $(( ($(date +%s%N) - t0) / 1000000 )) ms from simulate to the comparison"
}
field_loop hand40 "40 Hz hand" --rate 40 --count 4 --seed 7
field_loop suction71 "71 Hz suction" --sensor suction --count 3 --seed 2
