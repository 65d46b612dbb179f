#!/usr/bin/env bash
# Budgets report: flash and static RAM of the release firmware ELF with the default model blob,
# instructions and estimated Cortex-M4 cycles per 16-channel frame under QEMU, per part
# (scripts/qemu-bench.sh's cycle report), and the CPU share of a 168 MHz Cortex-M4 at 16.7 Hz and
# 40 Hz from the cycles. A report, not a timed test: it exits 0 whatever the figures, unless
# `--strict` is given (then 1 when a target is missed).
#
# Targets: flash ≤ 256 KiB; static RAM without the model's RAM image ≤ 48 KiB, with it ≤ 112 KiB
# (16 KiB of the 128 KiB SRAM left for the stack); 16 channels at 40 Hz within 44 % of the CPU.
# Method: sizes from `arm-none-eabi-size -A` (flash = every loaded section: vector table, text,
# rodata, .data's load image, the .model blob; RAM = .data + .bss + .uninit, stack excluded; the
# model image is the MODEL_RAM symbol's size); instructions = mean of `App::infer` over the 400
# frames of the recorded trial in the QEMU build with feature `all-contact` (SysTick at 40
# instructions per tick; every channel held in contact, so every channel runs the model every
# frame: the worst case, whereas the firmware runs the model only on the channels in contact), cycles = the same span under the project's cycle-estimate plugin
# (firmware/qemu-bench/plugin/README.md: Cortex-M4 timings, STM32F4 flash at 5 wait states behind
# the ART accelerator, sequential fetch at one 16-byte line per 6 cycles; beside it the figure with
# sequential fetch free, the model's first version). The DWT cycle counts the firmware logs on hardware are the final word.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
strict=0
[ "${1:-}" = "--strict" ] && strict=1

# Both binaries are in the firmware workspace (one target directory); one package per build, as
# the board and QEMU binaries cannot share one feature resolution.
(cd "$root/firmware" && cargo build --release -q -p slipguard-firmware)
elf="${CARGO_TARGET_DIR:-$root/firmware/target}/thumbv7em-none-eabihf/release/slipguard-firmware"
(cd "$root/firmware" && cargo build --release -q -p slipguard-qemu-app --features all-contact)
qelf="${CARGO_TARGET_DIR:-$root/firmware/target}/thumbv7em-none-eabihf/release/slipguard-qemu-app"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

echo "== firmware release ELF: $elf"
arm-none-eabi-size -A "$elf" | awk '$2 ~ /^[0-9]+$/ && $2 > 0 && $1 !~ /^\.(debug|comment|ARM|defmt|symtab|strtab)/ && $1 != "Total"'
read -r flash model ram < <(arm-none-eabi-size -A "$elf" | awk '
  $1 == ".vector_table" || $1 == ".text" || $1 == ".rodata" || $1 == ".data" { f += $2 }
  $1 == ".model" { m += $2 }
  $1 == ".data" || $1 == ".bss" || $1 == ".uninit" { r += $2 }
  END { print f + m, m, r }')

# (awk reads all of nm's output: an early exit would end nm with SIGPIPE under pipefail.)
model_ram_hex="$(arm-none-eabi-nm -S -C "$elf" | awk '$4 ~ /MODEL_RAM/ && h == "" { h = $2 } END { print h }')"
model_ram=$((16#${model_ram_hex:-0}))

# Per part: the QEMU bench with the cycle plugin (its table and `cycles:` line).
QEMU_BENCH_OUT="$work/bench" "$root/scripts/qemu-bench.sh" -q >"$work/bench.txt" 2>&1 || {
  cat "$work/bench.txt"; echo "budgets: the QEMU bench failed" >&2; exit 1; }
gcc -O2 -shared -fPIC -o "$work/libm4cycles.so" "$root/firmware/qemu-bench/plugin/m4cycles.c"

(cd "$work" && timeout 300 qemu-system-arm -M mps2-an386 -nographic \
  -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off \
  -plugin "$work/libm4cycles.so" -d plugin \
  -kernel "$qelf" </dev/null >"$work/qemu.txt" 2>"$work/plugin.txt")
insns="$(sed -n 's/.*frame (App::infer): mean \([0-9]*\).*over \([0-9]*\) frames.*/\1/p' "$work/qemu.txt")"
frames="$(sed -n 's/.*frame (App::infer): mean [0-9]*.*over \([0-9]*\) frames.*/\1/p' "$work/qemu.txt")"
read -r span_n span_cycles span_stall span_fetch < <(awk '$2 == "span" && $3 == 1 { print $5, $15, $11, $13 }' "$work/plugin.txt")
model_line="$(grep -m1 'model ' "$work/qemu.txt" || true)"
[ -n "$insns" ] || { cat "$work/qemu.txt"; echo "budgets: no instruction count from QEMU" >&2; exit 1; }
[ "${span_n:-0}" = "$frames" ] || { cat "$work/plugin.txt"; echo "budgets: no cycle estimate for App::infer from QEMU" >&2; exit 1; }

echo
sed -n '/^== Cortex-M4 cycle estimate per part/,/^cycles: /p' "$work/bench.txt"

# The closed-loop simulation's modelled inference time (host-tools/learn/src/closed_loop.rs), checked
# against this frame's estimate below.
inference_s="$(sed -n 's/^pub const INFERENCE_S: f64 = \([0-9.]*\);.*/\1/p' "$root/host-tools/learn/src/closed_loop.rs")"

awk -v flash="$flash" -v model="$model" -v ram="$ram" -v model_ram="$model_ram" -v insns="$insns" \
  -v cycles="$span_cycles" -v stall="$span_stall" -v fetch="$span_fetch" -v frames="$frames" -v strict="$strict" -v ml="$model_line" \
  -v inference_s="${inference_s:-0}" '
function kib(b) { return sprintf("%.1f KiB", b / 1024) }
BEGIN {
  ok = 1
  printf "\n== budgets (%s)\n", ml
  fl = flash <= 256 * 1024; ok = ok && fl
  printf "flash:      %8d B = %s (code+data %s, model blob %s)   target <= 256 KiB: %s\n", flash, kib(flash), kib(flash - model), kib(model), fl ? "ok" : "OVER"
  rest = ram - model_ram
  rm = rest <= 48 * 1024 && ram <= 112 * 1024; ok = ok && rm
  printf "static RAM: %8d B = %s (.data + .bss + .uninit): model RAM image %s + the rest %s   target <= 112 KiB with <= 48 KiB besides the image: %s\n", ram, kib(ram), kib(model_ram), kib(rest), rm ? "ok" : "OVER"
  printf "stack left in the 128 KiB SRAM: %s\n", kib(128 * 1024 - ram)
  c = cycles / frames
  printf "16-channel frame, every channel in contact (QEMU, App::infer, mean of %d frames): %d insns (%d per channel step), %d est. cycles (%d per channel step, flash stall %.1f %%)\n", frames, insns, insns / 16, c, c / 16, 100 * stall / cycles
  s16 = c * 16.7 / 168e6 * 100
  s40 = c * 40 / 168e6 * 100
  printf "CPU share at 168 MHz from the estimated cycles: 16.7 Hz %.1f %%, 40 Hz %.1f %% (at 1 insn/cycle: %.1f %%, %.1f %%)\n", s16, s40, insns * 16.7 / 168e6 * 100, insns * 40 / 168e6 * 100
  cf = (cycles - fetch) / frames
  printf "with sequential fetch free (the cycle model without its fetch-bandwidth term, fetchbw=0): %d est. cycles per frame (%d per channel step), 16.7 Hz %.1f %%, 40 Hz %.1f %%\n", cf, cf / 16, cf * 16.7 / 168e6 * 100, cf * 40 / 168e6 * 100
  t = s40 <= 44; ok = ok && t
  printf "target: 16 channels at 40 Hz within 44 %% of the CPU (estimated cycles): %s\n", t ? "ok" : "OVER"
  ms = c / 168e6 * 1000
  same = inference_s > 0 && ms / (1000 * inference_s) > 0.95 && ms / (1000 * inference_s) < 1.05
  printf "16-channel frame at 168 MHz: %.1f ms; the closed loop models %.1f ms (closed_loop::INFERENCE_S): %s\n", ms, 1000 * inference_s, same ? "ok (within 5 %)" : "differs: update INFERENCE_S"
  if (strict && !ok) exit 1
}'
