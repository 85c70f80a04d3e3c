# shellcheck shell=sh
# Helpers for VM scenario scripts. POSIX sh: sourced by the guest's /init (busybox ash) and by
# native.sh (the host's sh), so a scenario runs unchanged in both.
#
# A scenario sees:
#   RESULTS          directory whose files the host reads back (9p share in the guest)
#   FLYD_CAN         the CAN interface (vcan0)
#   FLYD_CAM_LEFT    v4l2loopback device labelled flyd-left  (e.g. /dev/video0)
#   FLYD_CAM_RIGHT   v4l2loopback device labelled flyd-right (e.g. /dev/video1)
#   FLYD_VM_BACKEND  qemu or native
# and the binaries under test on PATH, by their file names.

# Prints a marker the host parses from the console: @@RESULT name=NAME k=v ...@@
# Values must not contain spaces or "@@".
vm_result() {
    _name="$1"
    shift
    echo "@@RESULT name=$_name $*@@"
}

# Marker for the harness itself: @@VM event=EVENT k=v ...@@
vm_event() {
    _event="$1"
    shift
    echo "@@VM event=$_event uptime=$(vm_uptime) $*@@"
}

vm_uptime() {
    cut -d' ' -f1 /proc/uptime
}

# vm_wait_for SECONDS CMD...: runs CMD every 0.1 s until it succeeds; fails after SECONDS.
vm_wait_for() {
    _deadline=$(($1 * 10))
    shift
    _i=0
    until "$@"; do
        _i=$((_i + 1))
        if [ "$_i" -ge "$_deadline" ]; then
            echo "vm_wait_for: timed out: $*" >&2
            return 1
        fi
        sleep 0.1
    done
}

# vm_find_video LABEL: prints /dev/videoN whose V4L2 card name is LABEL (the v4l2loopback
# card_label), so scenarios do not depend on device numbering (a laptop has its own cameras).
vm_find_video() {
    for _n in /sys/class/video4linux/video*; do
        [ -r "$_n/name" ] || continue
        if [ "$(cat "$_n/name")" = "$1" ]; then
            echo "/dev/${_n##*/}"
            return 0
        fi
    done
    return 1
}

# vm_can_is_up IFACE: true when the interface exists and is administratively up.
vm_can_is_up() {
    [ -r "/sys/class/net/$1/flags" ] || return 1
    [ $(($(cat "/sys/class/net/$1/flags") & 1)) -eq 1 ]
}

# vm_can_receivers IFACE: prints how many CAN sockets receive on IFACE (all filter lists in
# /proc/net/can), so a scenario can wait until a listener (candump, flyd) has bound before
# sending: vm_wait_for 10 vm_can_receivers_above "$FLYD_CAN" "$before"
vm_can_receivers() {
    cat /proc/net/can/rcvlist_* 2>/dev/null | grep -c "^ *$1 " || true
}

# vm_can_receivers_above IFACE N: true when more than N sockets receive on IFACE.
vm_can_receivers_above() {
    [ "$(vm_can_receivers "$1")" -gt "$2" ]
}

# Exports the scenario environment, failing with a message when a device is missing.
vm_scenario_env() {
    FLYD_CAN=vcan0
    if ! vm_can_is_up "$FLYD_CAN"; then
        echo "vm: $FLYD_CAN is missing or down" >&2
        return 1
    fi
    if ! FLYD_CAM_LEFT="$(vm_find_video flyd-left)"; then
        echo "vm: no v4l2loopback device labelled flyd-left" >&2
        return 1
    fi
    if ! FLYD_CAM_RIGHT="$(vm_find_video flyd-right)"; then
        echo "vm: no v4l2loopback device labelled flyd-right" >&2
        return 1
    fi
    export RESULTS FLYD_CAN FLYD_CAM_LEFT FLYD_CAM_RIGHT FLYD_VM_BACKEND
}
