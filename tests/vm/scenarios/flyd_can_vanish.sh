#!/bin/sh
# The CAN adapter vanishes under flyd and comes back (a USB adapter re-enumerating): `ip link
# del vcan0` (writes fail with ENODEV: the socket's device is gone), 20 feeder frames (2 s at
# 10 fps), `ip link add vcan0 type vcan` and up. flyd must keep running, reopen the interface
# with backoff and send again on the new one.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road
flyd_wait_frame 20 60
ip link del "$FLYD_CAN"
flyd_event_after can-gone
flyd_wait_frame 40 60
flyd_event can-back
ip link add dev "$FLYD_CAN" type vcan
ip link set "$FLYD_CAN" up
# candump ends with its interface; a new one listens on the new interface, appending.
if kill -0 "$CANDUMP" 2>/dev/null; then kill "$CANDUMP" 2>/dev/null || true; fi
wait "$CANDUMP" 2>/dev/null || true
candump -r 4194304 -L "$FLYD_CAN" >>"$RESULTS/candump.log" &
CANDUMP=$!
vm_wait_for 10 vm_can_receivers_above "$FLYD_CAN" 0
kill -0 "$FLYD" || { echo "flyd died while $FLYD_CAN was gone" >&2; exit 1; }
flyd_wait_frame 80 60
flyd_stop
