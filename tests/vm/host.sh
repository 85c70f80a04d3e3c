# shellcheck shell=bash
# Host-side helpers shared by prepare.sh and run.sh (bash, sourced).

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
