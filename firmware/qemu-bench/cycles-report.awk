# Joins the QEMU bench's output (semihosting: `bench NAME: N insns/iter (I iterations, T insns)
# [span K]` lines and one `parts:` line) with the cycle plugin's span totals (`m4cycles: span K n
# … insns … base_cycles … flash_stall … est_cycles …`) and prints, per part, instructions and
# estimated cycles per call, cycles per MAC, the flash-stall share and the CPU share of a
# 168 MHz Cortex-M4 for 16 channels at 16.7 and 40 Hz; then the machine-readable line
#   cycles: step=N per_mac=X lstm=M frame40_pct=Z
# Cycles per call = (span cycles − calibration cycles per iteration × iterations) / iterations:
# the bookkeeping of the instruction counter (an empty body, measured the same way) is taken
# out as it is from the instruction counts. Used by scripts/qemu-bench.sh and scripts/budgets.sh.
# Input: both streams, in any order. Exit status 1 if a part is missing.

/^bench .*\[span [0-9]+\]$/ {
  line = $0
  sub(/^bench /, "", line)
  name = line; sub(/: [0-9]+ insns\/iter.*$/, "", name)
  rest = line; sub(/^.*: /, "", rest)
  split(rest, w, " ")
  span = $NF; sub(/\]$/, "", span)
  bname[span] = name
  binsns[span] = w[1]
  iters = rest; sub(/^[0-9]+ insns\/iter \(/, "", iters); sub(/ iterations.*$/, "", iters)
  biters[span] = iters
  next
}
/^parts: / {
  for (i = 2; i <= NF; i++) { split($i, kv, "="); part[kv[1]] = kv[2] }
  next
}
/^m4cycles: span / {
  s = $3
  for (i = 4; i < NF; i += 2) cyc[s, $i] = $(i + 1)
  measured[s] = 1
  next
}
function per_call(s,   c, it, cal) {
  it = biters[s]
  cal = cyc[part["calibration"], "est_cycles"] / part["calibration_iters"]
  c = (cyc[s, "est_cycles"] - cal * it) / it
  return c
}
function stall_pct(s) {
  return cyc[s, "est_cycles"] > 0 ? 100 * cyc[s, "flash_stall"] / cyc[s, "est_cycles"] : 0
}
function row(label, s, macs, channels,   c) {
  if (!(s in bname) || !(s in measured)) { missing = missing " " label; return }
  c = per_call(s)
  printf "%-40s %9d %12d %10s %11.1f %% %11.1f %% %11.1f %%\n", label, binsns[s], c + 0.5,
    (macs > 0 ? sprintf("%.2f", c / macs) : ""), stall_pct(s),
    c * channels * 16.7 / 168e6 * 100, c * channels * 40 / 168e6 * 100
}
END {
  if (!("step" in part)) { print "cycles-report: no parts line in the bench output" > "/dev/stderr"; exit 1 }
  macs = part["macs"]; lmacs = part["lstm_macs"]
  printf "\n== Cortex-M4 cycle estimate per part (plugin m4cycles, model in firmware/qemu-bench/plugin/README.md)\n"
  printf "%-40s %9s %12s %10s %13s %13s %13s\n", "part (per call)", "insns", "est. cycles", "cycles/MAC", "flash stall", "16 ch 16.7 Hz", "16 ch 40 Hz"
  row("channel step (weights in RAM)", part["step"], macs, 16)
  row("channel step, weights read from flash", part["step_flash"], macs, 16)
  row("channel step, plain RAM copy, row kernel", part["step_plain"], macs, 16)
  row("LSTM cell (11 -> 128)", part["lstm"], lmacs, 16)
  row("STFT (N = 20, 10 bands)", part["stft"], 0, 16)
  row("dense + softmax (128 -> p)", part["dense"], 0, 16)
  row("16-channel frame (16 channel steps)", part["frame"], 16 * macs, 1)
  if (missing != "") { print "cycles-report: no figures for:" missing > "/dev/stderr"; exit 1 }
  step = per_call(part["step"]); lstm = per_call(part["lstm"]); frame = per_call(part["frame"])
  printf "cycles: step=%d per_mac=%.2f lstm=%d frame40_pct=%.1f\n", step + 0.5, step / macs, lstm + 0.5, frame * 40 / 168e6 * 100
}
