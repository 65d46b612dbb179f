# Joins the QEMU bench's output (semihosting: `bench NAME: N insns/iter (I iterations, T insns)
# [span K]` lines and one `parts:` line) with the cycle plugin's span totals (`m4cycles: span K n
# … insns … base_cycles … flash_stall … fetch_stall … est_cycles …`) and prints, per part,
# instructions and estimated cycles per call, cycles per MAC, the flash-stall share and the CPU
# share of a 168 MHz Cortex-M4 for 16 channels at 16.7 and 40 Hz, and beside them the cycles with
# sequential fetch free (the model's first version: est_cycles − fetch_stall); then the
# machine-readable line
#   cycles: step=N per_mac=X lstm=M frame40_pct=Z seqfree_step=N seqfree_frame40_pct=Z
# and the fetch-bandwidth check: the bench's `fetch probe:` spans (a straight-line block of
# 32-bit instructions 4 times the I-cache, and a loop resident in it) must run at no better than
# 4 instructions per 6 cycles and at better than 1.2 cycles per instruction respectively (exit
# status 1 otherwise). With `-v fetchbw=0` (the plugin run with fetchbw=0) the first is skipped.
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
/^fetch probe: / {
  for (i = 3; i <= NF; i++) { split($i, kv, "="); probe[kv[1]] = kv[2] }
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
# The same with sequential fetch free: the fetch-bandwidth stall taken out of both spans.
function per_call_free(s,   c, it, cal, k) {
  it = biters[s]; k = part["calibration"]
  cal = (cyc[k, "est_cycles"] - cyc[k, "fetch_stall"]) / part["calibration_iters"]
  c = (cyc[s, "est_cycles"] - cyc[s, "fetch_stall"] - cal * it) / it
  return c
}
function stall_pct(s) {
  return cyc[s, "est_cycles"] > 0 ? 100 * cyc[s, "flash_stall"] / cyc[s, "est_cycles"] : 0
}
function row(label, s, macs, channels,   c, f) {
  if (!(s in bname) || !(s in measured)) { missing = missing " " label; return }
  c = per_call(s); f = per_call_free(s)
  printf "%-40s %9d %12d %10s %11.1f %% %11.1f %% %11.1f %% %12d %11.1f %%\n", label, binsns[s], c + 0.5,
    (macs > 0 ? sprintf("%.2f", c / macs) : ""), stall_pct(s),
    c * channels * 16.7 / 168e6 * 100, c * channels * 40 / 168e6 * 100,
    f + 0.5, f * channels * 40 / 168e6 * 100
}
# est. cycles per instruction of a fetch-probe span.
function cpi(s) { return cyc[s, "insns"] > 0 ? cyc[s, "est_cycles"] / cyc[s, "insns"] : 0 }
END {
  if (!("step" in part)) { print "cycles-report: no parts line in the bench output" > "/dev/stderr"; exit 1 }
  macs = part["macs"]; lmacs = part["lstm_macs"]
  printf "\n== Cortex-M4 cycle estimate per part (plugin m4cycles, model in firmware/qemu-bench/plugin/README.md)\n"
  printf "%-40s %9s %12s %10s %13s %13s %13s %12s %13s\n", "part (per call)", "insns", "est. cycles", "cycles/MAC", "flash stall", "16 ch 16.7 Hz", "16 ch 40 Hz", "seq. fetch", "free: 40 Hz"
  row("channel step (weights in RAM)", part["step"], macs, 16)
  row("channel step, weights read from flash", part["step_flash"], macs, 16)
  row("channel step, plain RAM copy, row kernel", part["step_plain"], macs, 16)
  row("LSTM cell (11 -> 128)", part["lstm"], lmacs, 16)
  row("STFT (N = 20, 10 bands)", part["stft"], 0, 16)
  row("dense + softmax (128 -> p)", part["dense"], 0, 16)
  row("16-channel frame (16 channel steps)", part["frame"], 16 * macs, 1)
  if (missing != "") { print "cycles-report: no figures for:" missing > "/dev/stderr"; exit 1 }
  step = per_call(part["step"]); lstm = per_call(part["lstm"]); frame = per_call(part["frame"])
  printf "cycles: step=%d per_mac=%.2f lstm=%d frame40_pct=%.1f seqfree_step=%d seqfree_frame40_pct=%.1f\n", step + 0.5, step / macs, lstm + 0.5, frame * 40 / 168e6 * 100, per_call_free(part["step"]) + 0.5, per_call_free(part["frame"]) * 40 / 168e6 * 100
  # The fetch-bandwidth check (plugin/README.md, "Model").
  if (!("straight" in probe) || !((probe["straight"], "insns") in cyc) || !((probe["loop"], "insns") in cyc)) {
    print "cycles-report: no fetch-probe spans in the bench output" > "/dev/stderr"; exit 1
  }
  st = cpi(probe["straight"]); lp = cpi(probe["loop"])
  printf "fetch bandwidth: straight-line 32-bit code from flash (%d KiB, 4 times the I-cache) %.3f est. cycles/insn (no better than 6 per 4 = 1.5: %s); loop resident in the I-cache %.3f (below 1.2: %s)\n", probe["bytes"] / 1024, st, (fetchbw == "0" ? "not checked, fetchbw=0" : (st >= 1.5 ? "ok" : "FAIL")), lp, (lp < 1.2 ? "ok" : "FAIL")
  if ((fetchbw != "0" && st < 1.5) || lp >= 1.2) { print "cycles-report: the fetch-bandwidth check failed" > "/dev/stderr"; exit 1 }
}
