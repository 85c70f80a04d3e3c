#!/bin/sh
# The CAN interface goes down under flyd and comes back: `ip link set vcan0 down`, 20 feeder
# frames (2 s at 10 fps), `up`. The events bracket the quiet time from inside: can-down is no
# earlier than the `down`, can-up no later than the `up`. flyd must keep running, count the failed writes and send again.
# candump itself stops on a downed interface (ENETDOWN): it is restarted, appending.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road
flyd_wait_frame 20 60
ip link set "$FLYD_CAN" down
flyd_event_after can-down
flyd_wait_frame 40 60
flyd_event can-up
ip link set "$FLYD_CAN" up
if ! kill -0 "$CANDUMP" 2>/dev/null; then
    echo "candump exited when $FLYD_CAN went down; restarting it"
    _before="$(vm_can_receivers "$FLYD_CAN")"
    candump -r 4194304 -L "$FLYD_CAN" >>"$RESULTS/candump.log" &
    CANDUMP=$!
    vm_wait_for 10 vm_can_receivers_above "$FLYD_CAN" "$_before"
fi
kill -0 "$FLYD" || { echo "flyd died while $FLYD_CAN was down" >&2; exit 1; }
flyd_wait_frame 80 60
flyd_stop
