#!/usr/bin/env bash
# Cargo runner of the firmware workspace (`.cargo/config.toml`): `cargo run` calls it with the
# ELF and any arguments after `--`.
#
# - `slipguard-qemu-*` ELFs run under QEMU mps2-an386 (Cortex-M4F) with semihosting; with
#   `-icount shift=0` QEMU advances 1 ns per instruction, so SysTick counts instructions exactly.
# - The board binary is flashed with `probe-rs run` (firmware and MODEL region), which then
#   streams the defmt log. The chip is `$PROBE_RS_CHIP` if set, else read from the ELF: MODEL at
#   0x0806_0000 is the STM32F446RE build, anything else the STM32F405RG.
#   When probe-rs is missing, finds no probe or fails, this says so and what to do, and exits
#   with a non-zero status.
set -uo pipefail

elf="${1:?usage: cargo-runner.sh ELF [ARGS...] (cargo run calls it)}"
shift

case "$(basename "$elf")" in
slipguard-qemu-*)
  exec qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
    -icount shift=0,align=off,sleep=off -kernel "$elf" "$@"
  ;;
esac

install_hint="install it once (about 7 minutes): sudo apt-get install -y libudev-dev pkg-config && cargo install probe-rs-tools --locked"

chip="${PROBE_RS_CHIP:-}"
if [ -z "$chip" ]; then
  chip=STM32F405RGTx
  if command -v arm-none-eabi-nm >/dev/null 2>&1 &&
    arm-none-eabi-nm "$elf" 2>/dev/null | grep -qi '^08060000 . __smodel$'; then
    chip=STM32F446RETx
  fi
fi

if ! command -v probe-rs >/dev/null 2>&1; then
  echo "cargo run: the firmware is built ($elf), but probe-rs is not installed, so nothing was flashed." >&2
  echo "cargo run: $install_hint; then run cargo run --release again." >&2
  exit 127
fi

probe-rs run --chip "$chip" "$elf" "$@"
status=$?
# 130: interrupted (Ctrl-C ends the log stream); nothing to explain.
if [ "$status" -eq 0 ] || [ "$status" -eq 130 ]; then
  exit "$status"
fi
probes="$(probe-rs list 2>/dev/null || true)"
if ! printf '%s\n' "$probes" | grep -q '^\['; then
  echo "cargo run: no debug probe found, so nothing was flashed (the firmware is built: $elf)." >&2
  echo "cargo run: connect an SWD probe (ST-LINK, J-Link or CMSIS-DAP) to the board's SWDIO (PA13), SWCLK (PA14), GND and 3.3 V" >&2
  echo "cargo run: (a Nucleo: plug in the USB of its on-board ST-LINK), power the board, check that \`probe-rs list\` shows the probe" >&2
  echo "cargo run: (on Linux, install probe-rs' udev rules), then run cargo run --release again." >&2
else
  echo "cargo run: probe-rs failed (status $status) with chip $chip on the probe(s) below:" >&2
  printf '%s\n' "$probes" >&2
  echo "cargo run: check the SWD wiring and the board's power; for another chip set PROBE_RS_CHIP (e.g. PROBE_RS_CHIP=STM32F446RETx)." >&2
fi
exit "$status"
