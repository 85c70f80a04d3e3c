#!/usr/bin/env bash
# Builds, once, the Debian 12 root file system that the systemd scenario boots (systemd as
# PID 1): mmdebstrap from Debian's packages, customised by customize.sh, written to an ext4
# image. Cached by a hash of its inputs; never committed. Prints ROOTFS=<image>.
#
# Usage: tests/vm/systemd/rootfs.sh [CACHE_DIR]    (default: <repo>/target/vm-systemd)
#
# The image is booted read-only in effect: QEMU opens it with snapshot=on, so every boot starts
# from the same pristine system and nothing it writes comes back here.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../../.." && pwd)"
cache="${1:-$repo/target/vm-systemd}"
mkdir -p "$cache"
cache="$(cd "$cache" && pwd)"

log() { echo "rootfs: $*" >&2; }
die() { echo "rootfs: ERROR: $*" >&2; exit 1; }

# What a vehicle PC's base system has for flyd: systemd with udev (which gives /dev/video*
# group video), journald, and the CAN tools the scenario uses (candump; ip for vcan0).
# Recommends are not installed (mmdebstrap's default): the smallest system the package must
# install on.
suite=bookworm
packages=(systemd systemd-sysv udev libnss-systemd can-utils iproute2 kmod procps)
mirrors=(
    "deb http://deb.debian.org/debian $suite main"
    "deb http://deb.debian.org/debian $suite-updates main"
    "deb http://deb.debian.org/debian-security $suite-security main"
)

key="$( {
    echo "$suite ${packages[*]} ${mirrors[*]}"
    cat "${BASH_SOURCE[0]}" "$here/customize.sh" "$here/flyd-vm-scenario" \
        "$here/flyd-vm-scenario.service"
} | sha256sum | cut -c1-16)"
image="$cache/rootfs-$key.ext4"

exec 9>"$cache/.lock"
flock -w 1800 9 || die "could not lock $cache/.lock within 30 min"

if [[ ! -f "$image" ]]; then
    command -v mmdebstrap >/dev/null || die "mmdebstrap missing: run .ci/vm-prereqs as root"
    [[ "$(id -u)" == 0 ]] || die "mmdebstrap --mode=root needs root"
    t0=$SECONDS
    tmp="$(mktemp -d "$cache/tmp.XXXXXX")"
    trap 'rm -rf "$tmp"' EXIT
    log "mmdebstrap $suite: ${packages[*]}"
    # Manual pages and translations are of no use in the test system (the package's own
    # files, docs included, are all kept).
    mmdebstrap --quiet --mode=root --variant=minbase \
        --include="$(IFS=,; echo "${packages[*]}")" \
        --dpkgopt='path-exclude=/usr/share/man/*' \
        --dpkgopt='path-exclude=/usr/share/locale/*' \
        --customize-hook="\"$here/customize.sh\" \"\$1\" \"$here\"" \
        "$suite" "$tmp/root" "${mirrors[@]}" </dev/null >&2
    log "root file system of $(du -sh "$tmp/root" | cut -f1) in $((SECONDS - t0)) s"
    # An ext4 image populated from the directory (mke2fs -d: no loop mount, no root needed).
    mkfs.ext4 -q -F -L flyd-vm -E root_owner=0:0 -d "$tmp/root" "$tmp/rootfs.ext4" 1536M
    mv "$tmp/rootfs.ext4" "$image"
    log "rootfs image $image in $((SECONDS - t0)) s"
fi
# Another worktree may use an older image: prune only those unused for a few days.
touch "$image"
find "$cache" -maxdepth 1 -name 'rootfs-*.ext4' -mtime +3 -delete
echo "ROOTFS=$image"
