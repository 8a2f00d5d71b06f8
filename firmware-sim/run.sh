#!/usr/bin/env bash
# firmware-sim/run.sh: builds the soft-sensor firmware for the Cortex-M4F, runs it under QEMU
# (mps2-an386, semihosting, -icount shift=0) and checks that its final state hashes equal the
# golden values of the host replay (recordings/<name>.golden, written by the sieve-tests test
# `sensor_golden`) and that no tick exceeds the cost model, for each recording: the shear cell
# (recordings/shear-cell.rec) and a discharging silo (recordings/silo.rec). Also runs the same
# loop built for the host and compares.
#
# Usage: firmware-sim/run.sh [--no-host] [--native]
#   --no-host   skip the host build of the loop
#   --native    also run the host build with RUSTFLAGS="-C target-cpu=native" (own target dir)
# Environment: SIEVE_RECORDING=/path/file.rec checks that recording alone (golden file next to
#   it, same name with .golden, if present); QEMU_TIMEOUT seconds (default 300);
#   SIEVE_QEMU_INSTALL = what to do if qemu-system-arm is not on PATH (see "QEMU" below):
#     auto (default)  system-wide apt install if root (or passwordless sudo) and it removes
#                     nothing, else a private copy in firmware-sim/target/qemu
#     system          only the system-wide install (refused if apt would remove a package)
#     local           only the private copy (apt-get download + dpkg-deb -x; no root needed)
#     no              install nothing; exit 11 with instructions
#
# Exit codes: 0 ok | 2 bad option | 10 Rust target install failed | 11 no QEMU (install refused
#             or failed) | 12 build failed
#             13 QEMU run failed or timed out | 14 hash differs from golden | 15 host differs
#             16 a tick executed more instructions than the cost model gives it
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
# QEMU: qemu-system-arm with the mps2-an386 machine (QEMU >= 6.0). Used from PATH if there;
# else from a private copy unpacked earlier into target/qemu; else installed as SIEVE_QEMU_INSTALL
# says. Whatever it does, this script says what before it does it, installs only Debian's
# qemu-system-arm and the libraries it needs (--no-install-recommends: 25 packages, 15.8 MB
# download, 68.5 MB on disk on Debian 12, against 165 packages + 7 upgrades, 157 MB download
# and 855 MB on disk with recommends),
# and never removes a package: the apt-get simulation runs first, and if apt would remove
# anything (e.g. a newer qemu-utils from backports Breaks qemu-system-common 7.2), the system
# install is refused.
QEMU_LOCAL="$PWD/target/qemu"
qemu_local_ready() { [ -x "$QEMU_LOCAL/bin/qemu-system-arm" ]; }
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo -n "$@"; fi; }
can_root() { [ "$(id -u)" -eq 0 ] || { command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; }; }
# Packages `apt-get install --no-install-recommends qemu-system-arm` would install (one per line),
# and the packages it would remove (in $QEMU_REMOVALS).
qemu_plan() {
  local sim
  if ! sim=$(apt-get -s install -y --no-install-recommends qemu-system-arm 2>&1); then
    echo "$sim" | tail -n 5 >&2
    return 1
  fi
  QEMU_PACKAGES=$(echo "$sim" | awk '/^Inst /{print $2}')
  QEMU_REMOVALS=$(echo "$sim" | awk '/^Remv /{print $2}')
}
qemu_sizes() { # download and installed size of the planned packages, from apt-cache
  # shellcheck disable=SC2086
  apt-cache show --no-all-versions $QEMU_PACKAGES 2>/dev/null | awk '
    /^Size:/ {d += $2} /^Installed-Size:/ {i += $2}
    END {printf "%.1f MB to download, %.1f MB on disk", d / 1e6, i * 1024 / 1e6}'
}
qemu_install_local() {
  echo "firmware-sim: unpacking a private QEMU into firmware-sim/target/qemu (apt-get download +"
  echo "  dpkg-deb -x: nothing is installed into or removed from the system; cargo clean removes it):"
  echo "  $(echo "$QEMU_PACKAGES" | wc -w) packages ($(qemu_sizes)):" $QEMU_PACKAGES
  local tmp
  tmp=$(mktemp -d) || return 1
  # shellcheck disable=SC2086
  if ! (cd "$tmp" && apt-get download $QEMU_PACKAGES); then
    rm -rf "$tmp"
    return 1
  fi
  rm -rf "$QEMU_LOCAL"
  mkdir -p "$QEMU_LOCAL/bin" "$QEMU_LOCAL/root"
  for deb in "$tmp"/*.deb; do dpkg-deb -x "$deb" "$QEMU_LOCAL/root" || { rm -rf "$tmp"; return 1; }; done
  rm -rf "$tmp"
  rm -f "$QEMU_LOCAL/root/usr/bin/qemu-system-aarch64" # 40 MB we do not run
  cat >"$QEMU_LOCAL/bin/qemu-system-arm" <<WRAP
#!/bin/sh
# Private QEMU unpacked by firmware-sim/run.sh: its libraries come from here, not the system.
R="$QEMU_LOCAL/root"
LD_LIBRARY_PATH="\$R/usr/lib/x86_64-linux-gnu:\$R/lib/x86_64-linux-gnu\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}" \\
  exec "\$R/usr/bin/qemu-system-arm" -L "\$R/usr/share/qemu" "\$@"
WRAP
  chmod +x "$QEMU_LOCAL/bin/qemu-system-arm"
  "$QEMU_LOCAL/bin/qemu-system-arm" -machine help | grep -q mps2-an386
}
qemu_missing() {
  loud "$1"
  cat >&2 <<'HELP'
firmware-sim needs qemu-system-arm (QEMU >= 6.0, machine mps2-an386) on PATH. Either
  - install it yourself (Debian/Ubuntu: apt-get install --no-install-recommends qemu-system-arm;
    first check with apt-get -s that it removes nothing), or
  - let this script unpack a private copy: SIEVE_QEMU_INSTALL=local bash firmware-sim/run.sh
    (apt-get download + dpkg-deb -x into firmware-sim/target/qemu; no root, nothing removed).
HELP
  exit 11
}
if ! command -v qemu-system-arm >/dev/null 2>&1; then
  if qemu_local_ready; then
    echo "firmware-sim: using the private QEMU in firmware-sim/target/qemu"
  else
    mode="${SIEVE_QEMU_INSTALL:-auto}"
    case "$mode" in
      auto | system | local) ;;
      no) qemu_missing "qemu-system-arm is not on PATH and SIEVE_QEMU_INSTALL=no" ;;
      *) echo "firmware-sim/run.sh: SIEVE_QEMU_INSTALL=$mode: allowed auto, system, local, no" >&2; exit 2 ;;
    esac
    command -v apt-get >/dev/null 2>&1 || qemu_missing "qemu-system-arm is not on PATH and this is not a Debian/Ubuntu system (no apt-get)"
    if can_root; then
      echo "firmware-sim: qemu-system-arm is not on PATH; refreshing the package lists (apt-get update)"
      as_root apt-get update -qq || qemu_missing "apt-get update failed"
    fi
    qemu_plan || qemu_missing "apt-get cannot plan an install of qemu-system-arm"
    [ -n "$QEMU_PACKAGES" ] || qemu_missing "apt-get plans no package for qemu-system-arm, yet it is not on PATH"
    if [ -n "$QEMU_REMOVALS" ]; then
      echo "firmware-sim: a system-wide install would REMOVE" $QEMU_REMOVALS "(apt-get -s); refusing it, nothing was changed" >&2
      [ "$mode" = system ] && qemu_missing "refusing SIEVE_QEMU_INSTALL=system: apt would remove $(echo $QEMU_REMOVALS)"
      mode=local
    fi
    if [ "$mode" = auto ]; then
      if can_root; then mode=system; else mode=local; fi
    fi
    if [ "$mode" = system ] && ! can_root; then
      qemu_missing "SIEVE_QEMU_INSTALL=system needs root or passwordless sudo"
    fi
    if [ "$mode" = system ]; then
      echo "firmware-sim: installing qemu-system-arm system-wide: apt-get install -y --no-install-recommends qemu-system-arm"
      echo "  $(echo "$QEMU_PACKAGES" | wc -w) new packages ($(qemu_sizes)), none removed:" $QEMU_PACKAGES
      if ! as_root apt-get install -y --no-install-recommends qemu-system-arm; then
        qemu_missing "installing QEMU failed: apt-get install -y --no-install-recommends qemu-system-arm"
      fi
    else
      qemu_install_local || qemu_missing "unpacking a private QEMU into firmware-sim/target/qemu failed"
    fi
  fi
fi
if ! command -v qemu-system-arm >/dev/null 2>&1 && qemu_local_ready; then
  export PATH="$QEMU_LOCAL/bin:$PATH"
fi
qemu-system-arm --version | head -n 1

# --- one recording: build it in, run it on the emulated Cortex-M4F and on the host ----------
# check_recording REC: the firmware's hashes against REC's golden file (same name, .golden),
# every tick against the cost model, and the host build of the loop against the firmware.
check_recording() {
  local rec=$1 name out golden status=0
  name=$(basename "${rec%.rec}")
  golden="${rec%.rec}.golden"
  out="target/firmware-sim-$name.log"
  echo "firmware-sim: recording $rec"
  if ! SIEVE_RECORDING="$rec" cargo build --release --target "$TARGET"; then
    loud "firmware build failed"
    return 12
  fi
  local elf="target/$TARGET/release/firmware-sim"
  for tool in llvm-size rust-size arm-none-eabi-size; do
    if command -v "$tool" >/dev/null 2>&1; then "$tool" -A "$elf" | grep -E '^\.(text|rodata|data|bss|uninit) '; break; fi
  done
  if ! SIEVE_RECORDING="$rec" timeout "${QEMU_TIMEOUT:-300}" cargo run --release --target "$TARGET" >"$out" 2>&1; then
    tail -n 20 "$out" >&2
    loud "QEMU run failed or timed out (log: firmware-sim/$out)"
    return 13
  fi
  grep -v '^est ' "$out"
  local fw_clean fw_fault
  fw_clean=$(grep -o 'final_state_hash=0x[0-9a-f]*' "$out" | head -n 1)
  fw_fault=$(grep -o 'faulted_state_hash=0x[0-9a-f]*' "$out" | head -n 1)
  if [ -f "$golden" ]; then
    for want in $(cat "$golden"); do
      if [ "$want" != "$fw_clean" ] && [ "$want" != "$fw_fault" ]; then
        loud "firmware hash differs from golden $want (firmware: $fw_clean $fw_fault)"
        status=14
      fi
    done
    [ $status -eq 0 ] && echo "firmware-sim: firmware hashes equal the golden host-replay hashes ($golden)"
  else
    echo "firmware-sim: no golden file $golden; comparing with the host build only"
  fi
  # The cost model caps every tick's substeps, so no tick may execute more instructions than
  # the model gives it (QEMU -icount counts are deterministic for a given build).
  local over
  over=$(grep -o 'ticks_over_model=[0-9]*' "$out" | grep -v '=0$' | head -n 1)
  if [ -z "$(grep -o 'ticks_over_model=' "$out")" ]; then
    loud "no cost_model line in the firmware log"
    status=16
  elif [ -n "$over" ]; then
    loud "the cost model under-counts a tick of $name ($over; raise CycleBudget::CORTEX_M4F in core/src/sensor/config.rs above the worst parts of the cost_model line and re-bless the recordings)"
    status=16
  else
    echo "firmware-sim: every tick within the cost model ($(grep -o 'max_tick_over_model=[0-9.]*' "$out" | tr '\n' ' '))"
  fi
  if [ $HOST -eq 1 ]; then host_check "$rec" "target/host-$name.log" "$fw_clean" "$fw_fault" || status=15; fi
  if [ $NATIVE -eq 1 ]; then
    CARGO_TARGET_DIR=target/native RUSTFLAGS="-C target-cpu=native" host_check "$rec" "target/host-native-$name.log" "$fw_clean" "$fw_fault" || status=15
  fi
  return $status
}

# --- the same loop on the host --------------------------------------------------------------
host_check() {
  local rec=$1 log=$2 fw_clean=$3 fw_fault=$4
  if ! SIEVE_RECORDING="$rec" cargo run --release >"$log" 2>&1; then
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

# --- the recordings: the shear cell and a discharging silo (or SIEVE_RECORDING alone) -------
mkdir -p target
if [ -n "${SIEVE_RECORDING:-}" ]; then
  RECS="$SIEVE_RECORDING"
else
  RECS="recordings/shear-cell.rec recordings/silo.rec"
fi
final=0
for rec in $RECS; do
  check_recording "$rec"
  rc=$?
  [ $rc -ne 0 ] && [ $final -eq 0 ] && final=$rc
done
exit $final
