#!/usr/bin/env bash
# Fetches and caches the guest kernel, builds v4l2loopback for it, and assembles the base
# initramfs (busybox, modules in load order, can-utils, /init). Prints, on stdout:
#   KVER=6.1.0-56-amd64
#   KERNEL=<cache>/<kver>/kernel     (vmlinux with a PVH entry, else the bzImage)
#   BASE=<cache>/<kver>/base-<key>.cpio.zst
#
# Cache: ${FLYD_VM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/flyd-vm}/<kver>/, outside git.
# Each step runs only when its output is missing; the whole script runs under one flock on
# <cache>/.lock, so parallel tests (and other worktrees) can call it at once.
#
# The guest kernel is the one Debian's `linux-image-amd64` depends on: the image, the headers
# (.ci/vm-prereqs installs them) and the v4l2loopback build all come from that one version.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
cache="${FLYD_VM_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/flyd-vm}"
mkdir -p "$cache"

# shellcheck source=tests/vm/host.sh
. "$here/host.sh"

log() { echo "prepare: $*" >&2; }
die() { echo "prepare: ERROR: $*" >&2; exit 1; }

exec 9>"$cache/.lock"
if ! flock -w 1800 9; then
    die "could not lock $cache/.lock within 30 min"
fi

guest_kernel() {
    apt-cache depends linux-image-amd64 2>/dev/null \
        | sed -n 's/^ *Depends: linux-image-\([0-9].*-amd64\)$/\1/p' | head -n1
}
kver="$(guest_kernel)"
# Without package lists (fresh machine) kver is empty here; vm-prereqs then updates them.
"$repo/.ci/vm-prereqs" ${kver:+--kernel "$kver"} \
    || die ".ci/vm-prereqs failed: the VM suite cannot run without it"
[[ -n "$kver" ]] || kver="$(guest_kernel)"
[[ -n "$kver" ]] || die "cannot resolve the guest kernel from linux-image-amd64 (apt-get update?)"
kdir="$cache/$kver"
mkdir -p "$kdir"
headers="/usr/src/linux-headers-$kver"
[[ -d "$headers" ]] || die "$headers missing although .ci/vm-prereqs passed"

# `apt-get download` into a directory; on failure (stale lists: the mirror has moved on) update
# the lists once and retry.
download() { # DIR PACKAGE
    local dir="$1" pkg="$2"
    # _apt cannot write into a root-owned mktemp dir; apt then warns and downloads as root.
    if ! (cd "$dir" && apt-get download -q "$pkg" 2> >(grep -v unsandboxed >&2) >&2); then
        [[ "$(id -u)" == 0 ]] || die "apt-get download $pkg failed"
        log "apt-get download $pkg failed; updating package lists and retrying"
        apt-get update -qq
        (cd "$dir" && apt-get download -q "$pkg" 2> >(grep -v unsandboxed >&2) >&2) \
            || die "apt-get download $pkg failed"
    fi
}

# 1. The kernel image package, unpacked: vmlinuz and /lib/modules/<kver>.
if [[ ! -f "$kdir/root/.complete" ]]; then
    t0=$SECONDS
    log "fetching linux-image-$kver"
    tmp="$(mktemp -d "$kdir/tmp.XXXXXX")"
    download "$tmp" "linux-image-$kver"
    rm -rf "$kdir/root"
    dpkg -x "$tmp"/linux-image-"$kver"_*.deb "$tmp/root"
    rm -f "$tmp"/*.deb
    touch "$tmp/root/.complete"
    mv "$tmp/root" "$kdir/root"
    rm -rf "$tmp"
    log "linux-image-$kver unpacked in $((SECONDS - t0)) s"
fi
[[ -f "$kdir/root/boot/vmlinuz-$kver" ]] || die "no vmlinuz-$kver in the image package"

# 1b. The uncompressed vmlinux, when it has a PVH entry note: QEMU then boots it directly, which
#     skips the bzImage's xz decompression: about 10 s of emulated CPU on every boot under TCG.
#     Without the note, the bzImage is booted as is.
extract_vmlinux() { # BZIMAGE OUT
    local img="$1" out="$2" i pos
    # stream magics (no NUL: bash strings cannot hold one) and their decompressors
    local magics=($'\xfd7zXZ' $'\x28\xb5\x2f\xfd' $'\x1f\x8b\x08')
    local cmds=("xz -dc" "zstd -qdc" "gzip -dc")
    for i in "${!magics[@]}"; do
        # shellcheck disable=SC2013 # offsets are single words
        for pos in $(LC_ALL=C grep -abo "${magics[$i]}" "$img" | cut -d: -f1); do
            # trailing bytes after the stream make the decompressor complain: ignore that
            tail -c+$((pos + 1)) "$img" | ${cmds[$i]} >"$out" 2>/dev/null || true
            if readelf -h "$out" >/dev/null 2>&1; then
                return 0
            fi
        done
    done
    return 1
}
if [[ ! -e "$kdir/kernel" ]]; then
    if extract_vmlinux "$kdir/root/boot/vmlinuz-$kver" "$kdir/vmlinux.tmp" \
        && readelf -n "$kdir/vmlinux.tmp" | grep -q 'Unknown note type: (0x00000012)'; then
        mv "$kdir/vmlinux.tmp" "$kdir/vmlinux"
        ln -sfn vmlinux "$kdir/kernel"
        log "booting the uncompressed vmlinux (PVH entry)"
    else
        rm -f "$kdir/vmlinux.tmp"
        ln -sfn "root/boot/vmlinuz-$kver" "$kdir/kernel"
        log "no PVH entry in vmlinux: booting the bzImage"
    fi
fi

# 2. v4l2loopback, built from Debian's dkms source against the guest's headers (not the host's:
#    the running host kernel is a different one). Never installed, so dkms never runs.
if [[ ! -f "$kdir/v4l2loopback.ko" ]]; then
    t0=$SECONDS
    log "building v4l2loopback for $kver"
    tmp="$(mktemp -d "$kdir/tmp.XXXXXX")"
    download "$tmp" v4l2loopback-dkms
    dpkg -x "$tmp"/v4l2loopback-dkms_*.deb "$tmp/pkg"
    src="$(echo "$tmp"/pkg/usr/src/v4l2loopback-*)"
    [[ -f "$src/v4l2loopback.c" ]] || die "no v4l2loopback source in v4l2loopback-dkms"
    make -s -C "$headers" M="$src" modules >&2
    modinfo -F vermagic "$src/v4l2loopback.ko" | grep -q "^$kver " \
        || die "v4l2loopback.ko was not built for $kver"
    cp "$src/v4l2loopback.ko" "$kdir/v4l2loopback.ko.tmp"
    mv "$kdir/v4l2loopback.ko.tmp" "$kdir/v4l2loopback.ko"
    rm -rf "$tmp"
    log "v4l2loopback built in $((SECONDS - t0)) s"
fi

# 3. The base initramfs. Its name carries a hash of everything that goes into it, so editing
#    /init, this script or the module list, or an upgraded busybox, rebuilds it.
#
# Leaf modules; `modprobe --show-depends` adds what they need, in load order (on 6.1:
# virtio*, netfs, fscache, 9pnet*, 9p; can, can-raw, can-dev, vcan; mc, videodev,
# videobuf2-*; virtio_blk, crc16, mbcache, jbd2, ext4). rc-core and cec are not dependencies of
# videodev in this kernel. virtio_blk and ext4: the systemd scenario's root file system
# (tests/vm/systemd).
modules=(virtio_pci 9pnet_virtio 9p can-raw vcan videobuf2-vmalloc v4l2loopback virtio_blk ext4)
declare -A module_params=(
    [v4l2loopback]="devices=2 exclusive_caps=0,0 card_label=flyd-left,flyd-right"
)
tools=(/bin/busybox /usr/bin/candump /usr/bin/cansend /usr/bin/cangen /usr/bin/canplayer)

key="$( {
    echo "$kver" "${modules[*]}" "${module_params[*]}"
    cat "${BASH_SOURCE[0]}" "$here/init" "$here/lib.sh" "$here/host.sh" "$kdir/v4l2loopback.ko" \
        "${tools[@]}" | sha256sum
} | sha256sum | cut -c1-16)"
base="$kdir/base-$key.cpio.zst"

if [[ ! -f "$base" ]]; then
    t0=$SECONDS
    log "assembling base initramfs $base"
    tmp="$(mktemp -d "$kdir/tmp.XXXXXX")"
    mroot="$kdir/root"
    mkdir -p "$mroot/lib/modules/$kver/updates"
    cp "$kdir/v4l2loopback.ko" "$mroot/lib/modules/$kver/updates/v4l2loopback.ko"
    depmod -b "$mroot" "$kver"

    r="$tmp/root"
    mkdir -p "$r"/{bin,sbin,usr/bin,usr/sbin,etc,proc,sys,dev,tmp,run,results,lib/modules}
    install -m 0755 "$here/init" "$r/init"
    install -D -m 0644 "$here/lib.sh" "$r/lib/flyd-vm/lib.sh"
    install -m 0755 /bin/busybox "$r/bin/busybox"
    for t in "${tools[@]:1}"; do
        copy_with_libs "$r" "$t" "/usr/bin/$(basename "$t")"
    done

    n=0
    declare -A seen=()
    : >"$r/etc/vm-modules"
    for m in "${modules[@]}"; do
        while read -r verb path _; do
            [[ "$verb" == insmod ]] || continue # "builtin x": nothing to load
            name="$(basename "$path")"
            name="${name%.xz}"; name="${name%.zst}"; name="${name%.gz}"; name="${name%.ko}"
            [[ -z "${seen[$name]:-}" ]] || continue
            seen[$name]=1
            n=$((n + 1))
            file="$(printf '%02d-%s.ko' "$n" "$name")"
            # The guest's busybox insmod takes plain .ko: decompress here if Debian compressed.
            case "$path" in
                *.ko.xz) xz -dc "$path" >"$r/lib/modules/$file" ;;
                *.ko.zst) zstd -qdc "$path" >"$r/lib/modules/$file" ;;
                *.ko.gz) gzip -dc "$path" >"$r/lib/modules/$file" ;;
                *) cp "$path" "$r/lib/modules/$file" ;;
            esac
            echo "$file ${module_params[$name]:-}" >>"$r/etc/vm-modules"
        done < <(modprobe -d "$mroot" -S "$kver" --show-depends "$m")
    done
    log "modules in load order: $(cut -d' ' -f1 "$r/etc/vm-modules" | tr '\n' ' ')"

    cpio_newc "$r" | zstd -q -T0 -10 >"$tmp/base.cpio.zst"
    mv "$tmp/base.cpio.zst" "$base"
    rm -rf "$tmp"
    log "base initramfs assembled in $((SECONDS - t0)) s ($(du -h "$base" | cut -f1))"
fi

# Another worktree may be booting an older base (its own init): prune only those unused for a
# few days. Using a base marks it used.
touch "$base"
find "$kdir" -maxdepth 1 -name 'base-*.cpio.zst' -mtime +3 -delete

echo "KVER=$kver"
echo "KERNEL=$kdir/kernel"
echo "BASE=$base"
