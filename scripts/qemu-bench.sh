#!/usr/bin/env bash
# Builds firmware/qemu-bench (a member of the firmware workspace) in release and the project's
# cycle-estimate plugin (firmware/qemu-bench/plugin/m4cycles.c, gcc), runs the bench under QEMU
# (mps2-an386,
# -icount shift=0) with the plugin and a timeout, and prints the bench's output (exact
# instruction counts, bit-exact checks), then per part the estimated Cortex-M4 cycles and CPU
# shares, the machine-readable `cycles:` line and where the channel step's cycles go (per
# function). Exits with the bench's own status (0 ok, 1 check mismatch, 101 panic, 124 timeout),
# or 1 if the cycle report is incomplete. Works from any directory. Extra arguments go to cargo,
# e.g. `--features wrap-check`.
# The estimate charges sequential instruction fetch from flash its bandwidth (plugin/README.md);
# beside it the report gives the figures with sequential fetch free (the model's first version),
# and it checks the fetch bandwidth on the bench's probe (cycles-report.awk).
# Env: QEMU_BENCH_TIMEOUT (seconds, default 300), QEMU_BENCH_OUT (keep the raw outputs in this
# directory), M4CYCLES_ARGS (more plugin arguments, comma-separated, e.g. `fetchbw=0`),
# M4CYCLES_REF (path of a reference m4cycles.c with one marker address per instance, e.g.
# /work/shared/tools/qemu-plugins/m4cycles.c: the channel step and frame are also estimated
# under it, one extra QEMU run with four instances of it, and printed as `reference:` lines).
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bench_dir="$root/firmware/qemu-bench"
timeout_s="${QEMU_BENCH_TIMEOUT:-300}"
work="${QEMU_BENCH_OUT:-$(mktemp -d)}"
mkdir -p "$work"
[ -n "${QEMU_BENCH_OUT:-}" ] || trap 'rm -rf "$work"' EXIT

(cd "$bench_dir" && cargo build --release "$@")
# The firmware workspace's one target directory. The plugin is passed to QEMU here, so the
# cargo runner (firmware/cargo-runner.sh, used by `cargo run`) is not involved.
elf="${CARGO_TARGET_DIR:-$root/firmware/target}/thumbv7em-none-eabihf/release/slipguard-qemu-bench"
gcc -O2 -Wall -Wextra -Wno-unused-parameter -shared -fPIC -o "$work/libm4cycles.so" "$bench_dir/plugin/m4cycles.c"

# The channel step's span (the bench's third measurement; checked against its `parts:` line
# below) is profiled per instruction address.
step_span=3
status=0
# No stdin: QEMU's -nographic monitor stays idle. The plugin writes to stderr.
timeout --kill-after=10 "$timeout_s" qemu-system-arm -M mps2-an386 -nographic \
  -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off \
  -plugin "$work/libm4cycles.so,prof=$work/profile.txt,profspan=$step_span${M4CYCLES_ARGS:+,$M4CYCLES_ARGS}" -d plugin \
  -kernel "$elf" </dev/null >"$work/bench.txt" 2>"$work/plugin.txt" || status=$?
cat "$work/bench.txt"
if [ "$status" -eq 124 ]; then
  echo "qemu-bench: timed out after ${timeout_s} s" >&2
  exit "$status"
elif [ "$status" -ne 0 ]; then
  cat "$work/plugin.txt" >&2
  echo "qemu-bench: failed with exit status $status" >&2
  exit "$status"
fi
fetchbw="$(printf ',%s,' "${M4CYCLES_ARGS:-}" | sed -n 's/.*,fetchbw=\([0-9]*\),.*/\1/p')"
cat "$work/bench.txt" "$work/plugin.txt" | awk -v fetchbw="${fetchbw:-1}" -f "$bench_dir/cycles-report.awk"

# The reference model: its marker lines are cumulative from the start at the first store to its
# `addr=`, so one instance per span end (calibration, channel step, frame: open and close) in
# one run; per call = (span − calibration per iteration × iterations) / iterations.
if [ -n "${M4CYCLES_REF:-}" ]; then
  gcc -O2 -shared -fPIC -o "$work/libref.so" "$M4CYCLES_REF"
  read -r cal step frame <<<"$(sed -n 's/^parts: .*step=\([0-9]*\) .*frame=\([0-9]*\) calibration=\([0-9]*\) .*/\3 \1 \2/p' "$work/bench.txt")"
  args=()
  for s in "$cal" "$step" "$frame"; do
    for end in 0 4; do
      cp "$work/libref.so" "$work/libref-$s-$end.so"
      args+=(-plugin "$work/libref-$s-$end.so,addr=$((0x20300000 + 8 * s + end))")
    done
  done
  timeout --kill-after=10 "$((4 * timeout_s))" qemu-system-arm -M mps2-an386 -nographic \
    -semihosting-config enable=on,target=native -icount shift=0,align=off,sleep=off \
    "${args[@]}" -d plugin -kernel "$elf" </dev/null >/dev/null 2>"$work/ref.txt"
  awk -v cal="$cal" -v step="$step" -v frame="$frame" -v ref="$M4CYCLES_REF" '
    FNR == NR && /^bench .*\[span [0-9]+\]$/ { s = $NF; sub(/\]$/, "", s); it = $0; sub(/^.*insns\/iter \(/, "", it); sub(/ iterations.*$/, "", it); iters[s] = it; next }
    FNR == NR && /^parts: / { for (i = 2; i <= NF; i++) { split($i, kv, "="); p[kv[1]] = kv[2] } next }
    FNR == NR { next }
    /^m4cycles: marker #0 / { v[++n] = $NF }
    END {
      if (n != 6) { print "qemu-bench: the reference model gave " n " of 6 marker lines" > "/dev/stderr"; exit 1 }
      c = (v[2] - v[1]) / p["calibration_iters"]
      st = (v[4] - v[3] - c * iters[step]) / iters[step]
      fr = (v[6] - v[5] - c * iters[frame]) / iters[frame]
      printf "reference model (%s): channel step %d est. cycles (%.2f per MAC), 16-channel frame %d, 16 ch at 40 Hz %.1f %% of 168 MHz\n", ref, st + 0.5, st / p["macs"], fr + 0.5, fr * 40 / 168e6 * 100
    }' "$work/bench.txt" "$work/ref.txt"
fi

# Per function: the profile's addresses mapped to the symbols that contain them.
if grep -q "^parts: step=$step_span " "$work/bench.txt"; then
  printf '\n== where the channel step goes (weights in RAM; per step, functions >= 0.5 %% of the cycles)\n'
  steps="$(sed -n 's/^bench channel step (variant.*(\([0-9]*\) iterations.*/\1/p' "$work/bench.txt")"
  arm-none-eabi-nm -S -n -C "$elf" >"$work/symbols.txt"
  python3 - "$work/symbols.txt" "$work/profile.txt" "$steps" <<'PY'
import bisect, sys
syms = []
for line in open(sys.argv[1]):
    f = line.split(maxsplit=3)
    if len(f) == 4 and f[2] in "tTwW":
        syms.append((int(f[0], 16), int(f[0], 16) + int(f[1], 16), f[3].strip()))
starts = [s[0] for s in syms]
steps = int(sys.argv[3])
acc = {}
for line in open(sys.argv[2]):
    pc, n, c, st = (int(x, 0) for x in line.split())
    k = bisect.bisect_right(starts, pc) - 1
    name = syms[k][2] if k >= 0 and pc < syms[k][1] else "?"
    a = acc.setdefault(name, [0, 0, 0])
    a[0] += n; a[1] += c; a[2] += st
total = sum(a[1] for a in acc.values()) or 1
print(f"{'function':<64} {'insns':>9} {'est. cycles':>11} {'share':>7} {'stall':>7}")
for name, (n, c, st) in sorted(acc.items(), key=lambda kv: -kv[1][1]):
    if c >= 0.005 * total:
        label = name if len(name) <= 64 else name[:61] + "..."
        print(f"{label:<64} {n // steps:>9} {c // steps:>11} {100 * c / total:>6.1f}% {st // steps:>7}")
PY
else
  echo "qemu-bench: the step is no longer span $step_span; per-function table skipped" >&2
fi
