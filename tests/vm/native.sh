#!/usr/bin/env bash
# Runs one scenario directly on this host, without QEMU: for a machine that already has vcan0
# and the two v4l2loopback cameras (a vehicle PC, a developer laptop). See README.md for the
# setup commands. Same arguments (less --kernel/--base), markers and exit status as run.sh.
#
# Usage: tests/vm/native.sh --script FILE --results DIR [--bin PATH]... [--timeout SECS]
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=tests/vm/host.sh
. "$here/host.sh"
parse_scenario_args native.sh 2,7p "$@"
script="$(cd "$(dirname "$script")" && pwd)/$(basename "$script")"
mkdir -p "$results"
results="$(cd "$results" && pwd)"
work="$(mktemp -d "${TMPDIR:-/tmp}/flyd-native.XXXXXX")"
trap 'rm -rf "$work"' EXIT

# The binaries under test go first on PATH, under their file names, as in the guest.
mkdir -p "$work/bin" "$work/cwd"
for b in "${bins[@]}"; do
    [[ -x "$b" ]] || { echo "native.sh: --bin $b is not an executable file" >&2; exit 2; }
    ln -s "$(readlink -f "$b")" "$work/bin/$(basename "$b")"
done
export PATH="$work/bin:$PATH"

set +e
(
    set -e
    # shellcheck source=tests/vm/lib.sh
    . "$here/lib.sh"
    RESULTS="$results"
    FLYD_VM_BACKEND=native
    if ! vm_scenario_env; then
        echo "native.sh: this host lacks the devices; see tests/vm/README.md (native runs)" >&2
        vm_event fail stage=scenario-env
        exit 125
    fi
    vm_event ready "can=$FLYD_CAN" "left=$FLYD_CAM_LEFT" "right=$FLYD_CAM_RIGHT"
    set +e
    # sh, as in the guest (busybox ash there, dash here): the same POSIX dialect.
    # shellcheck disable=SC2016 # $1.. expand in that sh, not here
    timeout --kill-after=5 "$timeout" \
        sh -c 'cd "$1" && . "$2" && . "$3"' sh "$work/cwd" "$here/lib.sh" "$script"
    code=$?
    if [[ $code -eq 124 || $code -eq 137 ]]; then
        echo "native.sh: TIMEOUT: scenario killed after ${timeout} s" >&2
        exit 124
    fi
    vm_event exit "code=$code"
    exit "$code"
) 2>&1 | tee "$results/console.log"
status=${PIPESTATUS[0]}
echo "native.sh: scenario exit=$status" >&2
exit "$status"
