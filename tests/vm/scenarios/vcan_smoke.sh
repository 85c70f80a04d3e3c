#!/bin/sh
# vcan smoke: a frame sent with cansend is seen by candump on the same bus.
set -eu
receivers=$(vm_can_receivers "$FLYD_CAN")
candump -L "$FLYD_CAN" >"$RESULTS/candump.log" &
dump=$!
# Send only once candump has bound, or the frame goes by unseen.
vm_wait_for 10 vm_can_receivers_above "$FLYD_CAN" "$receivers"
cansend "$FLYD_CAN" 123#DEADBEEF
vm_wait_for 10 grep -q ' 123#DEADBEEF' "$RESULTS/candump.log"
kill "$dump"
vm_result vcan sent=123#DEADBEEF
