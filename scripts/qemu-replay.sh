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
# Exit status 0 when both comparisons match, 1 on a mismatch, else the failing command's status.
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
b[5000] ^= 0x10
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
