#!/usr/bin/env bash
# firmware-sim/run.sh: builds the soft-sensor firmware for the Cortex-M4F, runs it under QEMU
# (mps2-an386, semihosting, -icount shift=0) and checks that its final state hashes equal the
# golden values of the host replay (recordings/<name>.golden, written by the sieve-tests test
# `sensor_golden`). Also runs the same loop built for the host and compares.
#
# Usage: firmware-sim/run.sh [--no-host] [--native]
#   --no-host   skip the host build of the loop
#   --native    also run the host build with RUSTFLAGS="-C target-cpu=native" (own target dir)
# Environment: SIEVE_RECORDING=/path/file.rec embeds another recording (golden file next to it,
#   same name with .golden, if present); QEMU_TIMEOUT seconds (default 300).
#
# Exit codes: 0 ok | 10 Rust target install failed | 11 qemu install failed | 12 build failed
#             13 QEMU run failed or timed out | 14 hash differs from golden | 15 host differs
set -u
cd "$(dirname "$0")"
TARGET=thumbv7em-none-eabihf
HOST=1
NATIVE=0
for a in "$@"; do
  case "$a" in
    --no-host) HOST=0 ;;
    --native) NATIVE=1 ;;
    *) echo "firmware-sim/run.sh: unknown option $a" >&2; exit 2 ;;
  esac
done
loud() { printf '\n!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n!!! firmware-sim: %s\n!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n\n' "$*" >&2; }

# --- toolchain: the Rust target and QEMU (Debian's qemu-system-arm) --------------------------
if ! rustup target list --installed 2>/dev/null | grep -qx "$TARGET"; then
  echo "firmware-sim: installing Rust target $TARGET"
  if ! rustup target add "$TARGET"; then
    loud "installing the Rust target failed: rustup target add $TARGET"
    exit 10
  fi
fi
if ! command -v qemu-system-arm >/dev/null 2>&1; then
  echo "firmware-sim: installing qemu-system-arm"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  if ! { $SUDO apt-get update && $SUDO apt-get install -y qemu-system-arm; }; then
    loud "installing QEMU failed: apt-get install -y qemu-system-arm"
    exit 11
  fi
fi
qemu-system-arm --version | head -n 1

# --- golden values ------------------------------------------------------------------------
REC="${SIEVE_RECORDING:-recordings/shear-cell.rec}"
GOLDEN="${REC%.rec}.golden"
OUT=target/firmware-sim.log
mkdir -p target

# --- build and run on the emulated Cortex-M4F ---------------------------------------------
if ! cargo build --release --target "$TARGET"; then
  loud "firmware build failed"
  exit 12
fi
ELF="target/$TARGET/release/firmware-sim"
for tool in llvm-size rust-size arm-none-eabi-size; do
  if command -v "$tool" >/dev/null 2>&1; then "$tool" -A "$ELF" | grep -E '^\.(text|rodata|data|bss|uninit) '; break; fi
done
if ! timeout "${QEMU_TIMEOUT:-300}" cargo run --release --target "$TARGET" >"$OUT" 2>&1; then
  tail -n 20 "$OUT" >&2
  loud "QEMU run failed or timed out (log: firmware-sim/$OUT)"
  exit 13
fi
grep -v '^est ' "$OUT"
fw_clean=$(grep -o 'final_state_hash=0x[0-9a-f]*' "$OUT" | head -n 1)
fw_fault=$(grep -o 'faulted_state_hash=0x[0-9a-f]*' "$OUT" | head -n 1)
status=0
if [ -f "$GOLDEN" ]; then
  for want in $(cat "$GOLDEN"); do
    if [ "$want" != "$fw_clean" ] && [ "$want" != "$fw_fault" ]; then
      loud "firmware hash differs from golden $want (firmware: $fw_clean $fw_fault)"
      status=14
    fi
  done
  [ $status -eq 0 ] && echo "firmware-sim: firmware hashes equal the golden host-replay hashes ($GOLDEN)"
else
  echo "firmware-sim: no golden file $GOLDEN; comparing with the host build only"
fi

# --- the same loop on the host --------------------------------------------------------------
host_check() {
  local log=$1
  if ! cargo run --release >"$log" 2>&1; then
    tail -n 20 "$log" >&2
    loud "host build of the loop failed"
    return 15
  fi
  local hc hf
  hc=$(grep -o 'final_state_hash=0x[0-9a-f]*' "$log" | head -n 1)
  hf=$(grep -o 'faulted_state_hash=0x[0-9a-f]*' "$log" | head -n 1)
  if [ "$hc" != "$fw_clean" ] || [ "$hf" != "$fw_fault" ]; then
    loud "host loop ($hc $hf) differs from firmware ($fw_clean $fw_fault)"
    return 15
  fi
  echo "firmware-sim: host loop hashes equal the firmware's ($log)"
}
if [ $HOST -eq 1 ]; then host_check target/host.log || status=15; fi
if [ $NATIVE -eq 1 ]; then
  CARGO_TARGET_DIR=target/native RUSTFLAGS="-C target-cpu=native" host_check target/host-native.log || status=15
fi
exit $status
