#!/usr/bin/env bash
# Boots one scenario in QEMU (TCG) and leaves its results on the host.
#
# Usage: tests/vm/run.sh --script FILE --results DIR [--bin PATH]... [--timeout SECS]
#                        [--kernel FILE --base FILE] [--rootfs IMAGE]
#
#   --script   guest scenario (sh), run by the guest's /init with lib.sh's environment
#   --results  host directory shared with the guest as $RESULTS (9p); console.log lands there
#   --bin      a binary under test, put on the guest's PATH (/usr/local/bin) under its file
#              name, with the shared libraries ldd finds for it; also any file a program
#              needs beside it (a script, a config). Repeatable.
#   --timeout  hard wall-clock limit for QEMU, default 180 s
#   --kernel, --base   the KERNEL and BASE that prepare.sh printed; without them run.sh runs
#              prepare.sh itself (a test driver runs it once for all its boots)
#   --rootfs   a Debian root file system image (tests/vm/systemd/rootfs.sh): /init switches
#              to it and systemd runs the scenario as PID 1's service (1.5 GB of guest memory;
#              the image is opened with snapshot=on, so it is never written)
#
# Exit status: the scenario's exit code when the VM ran it to the end and powered off;
# 124 when the timeout killed QEMU; 125 when the VM stopped before the scenario ended (setup
# failure, kernel panic, QEMU error). Each case is also said on stderr.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=tests/vm/host.sh
. "$here/host.sh"

parse_scenario_args run.sh 2,20p "$@"

if [[ -z "$KERNEL" || -z "$BASE" ]]; then
    eval "$("$here/prepare.sh")"
fi

mkdir -p "$results"
results="$(cd "$results" && pwd)"
work="$(mktemp -d "${TMPDIR:-/tmp}/flyd-vm.XXXXXX")"
trap 'rm -rf "$work"' EXIT

# The per-boot overlay: scenario and binaries under test, uncompressed (they change every
# build; compressing a large binary costs more than it saves). The kernel unpacks concatenated
# archives in order; this one goes first, uncompressed, as early-microcode archives do.
o="$work/overlay"
mkdir -p "$o/usr/local/bin"
install -m 0755 "$script" "$o/scenario.sh"
for b in "${bins[@]}"; do
    [[ -f "$b" ]] || { echo "run.sh: --bin $b is not a file" >&2; exit 2; }
    copy_with_libs "$o" "$b" "/usr/local/bin/$(basename "$b")"
done
cpio_newc "$o" >"$work/initrd"
cat "$BASE" >>"$work/initrd"

# 768 MB: the initramfs is unpacked into the guest's memory, and the overlay's release
# binaries (flyd ~80 MB, flyd-feeder ~70 MB, with debug info) with the base's modules came
# within a few MB of what 512 MB leaves ("Initramfs unpacking failed: write error" once
# virtio_blk and ext4 joined the base).
memory=768
append="console=ttyS0 quiet loglevel=3 panic=-1"
drive=()
if [[ -n "$ROOTFS" ]]; then
    [[ -f "$ROOTFS" ]] || { echo "run.sh: --rootfs $ROOTFS is not a file" >&2; exit 2; }
    memory=1536
    append+=" flyd.systemd"
    drive=(-drive "file=$ROOTFS,format=raw,if=virtio,snapshot=on")
fi

start=$EPOCHREALTIME
set +e
timeout --kill-after=5 "$timeout" qemu-system-x86_64 \
    -accel tcg -cpu max -m "$memory" -smp 2 \
    -nographic -no-reboot -nic none \
    -kernel "$KERNEL" -initrd "$work/initrd" "${drive[@]}" \
    -append "$append" \
    -virtfs "local,path=$results,mount_tag=results,security_model=none,id=results" \
    </dev/null >"$results/console.log" 2>"$work/qemu.err"
qemu_status=$?
set -e
wall=$(awk -v a="$start" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }')
tr -d '\r' <"$results/console.log" >"$work/console" && mv "$work/console" "$results/console.log"

if [[ $qemu_status -eq 124 || $qemu_status -eq 137 ]]; then
    echo "run.sh: TIMEOUT: QEMU killed after ${timeout} s; console in $results/console.log" >&2
    exit 124
fi
if [[ $qemu_status -ne 0 ]]; then
    echo "run.sh: QEMU failed (exit $qemu_status): $(cat "$work/qemu.err")" >&2
    exit 125
fi
code="$(sed -n 's/.*@@VM event=exit uptime=[^ ]* code=\([0-9]*\).*/\1/p' "$results/console.log")"
if [[ -z "$code" ]]; then
    echo "run.sh: the VM stopped before the scenario ended; console:" >&2
    tail -n 40 "$results/console.log" >&2
    exit 125
fi
echo "run.sh: scenario exit=$code qemu_wall_s=$wall" >&2
exit "$code"
