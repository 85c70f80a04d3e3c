# shellcheck shell=bash
# Host-side helpers shared by prepare.sh, run.sh and native.sh (bash, sourced).

# copy_with_libs ROOT BINARY DEST: installs BINARY at ROOT/DEST with the shared libraries ldd
# finds for it, at their host paths (the guest's ld.so has no cache; it searches the default
# directories, which are the same as the host's).
copy_with_libs() {
    local root="$1" bin="$2" dest="$3" lib
    install -D -m 0755 "$bin" "$root$dest"
    for lib in $(ldd "$bin" 2>/dev/null | grep -o '/[^ ]*' || true); do
        [[ -e "$root$lib" ]] || install -D -m 0755 "$(readlink -f "$lib")" "$root$lib"
    done
}

# cpio_newc DIR: writes DIR's tree as a newc archive, owned by root, in a stable order.
cpio_newc() {
    (cd "$1" && find . -mindepth 1 | LC_ALL=C sort | cpio -o -H newc -R 0:0 --quiet)
}

# parse_scenario_args NAME USAGE_LINES ARGS...: the arguments run.sh and native.sh share, into
# script, results, bins, timeout (default 180), KERNEL, BASE and ROOTFS (run.sh's only); a wrong one
# is said on stderr with the usage (lines USAGE_LINES of $0) and exits 2.
parse_scenario_args() {
    local name="$1" usage="$2"
    shift 2
    script="" results="" timeout=180 KERNEL="" BASE="" ROOTFS=""
    bins=()
    while [[ $# -gt 0 ]]; do
        case "$1" in
            --script) script="$2"; shift 2 ;;
            --results) results="$2"; shift 2 ;;
            --bin) bins+=("$2"); shift 2 ;;
            --timeout) timeout="$2"; shift 2 ;;
            --kernel | --base | --rootfs)
                [[ "$name" == run.sh ]] || { echo "$name: unknown argument $1" >&2; exit 2; }
                case "$1" in
                    --kernel) KERNEL="$2" ;;
                    --base) BASE="$2" ;;
                    --rootfs) ROOTFS="$2" ;;
                esac
                shift 2 ;;
            *) echo "$name: unknown argument $1" >&2; exit 2 ;;
        esac
    done
    [[ -f "$script" && -n "$results" ]] || { sed -n "$usage" "$0" >&2; exit 2; }
}
