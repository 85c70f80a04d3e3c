#!/bin/sh
# vcan smoke: a frame sent with cansend is seen by candump on the same bus.
set -eu
candump -L "$FLYD_CAN" >"$RESULTS/candump.log" &
dump=$!
sleep 0.5 # let candump bind before the frame goes out
cansend "$FLYD_CAN" 123#DEADBEEF
vm_wait_for 10 grep -q ' 123#DEADBEEF' "$RESULTS/candump.log"
kill "$dump"
vm_result vcan sent=123#DEADBEEF
