#!/bin/sh
# The vehicle's motion on vcan0: canplayer replays $RESULTS/input/motion.log (VCU_Motion every
# 20 ms, written by the host test: standing still, then driving off, then silence, with bad
# frames among the good ones) while the feeder plays pedestrian-4m. flyd starts without any
# motion (MotionFault, the assumed speed), sees the vehicle stand still, then drive off, then
# loses the motion when the log ends.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch pedestrian-4m
flyd_wait_frame 40 60
# The pedestrian (there from the start) confirmed and STOP sent at the assumed speed before the
# motion comes: under TCG that took 0.2-3 s after RUNNING. Then a second more of it (30 frames).
# Not found in 30 s: the host test says so ("the pedestrian confirmed").
vm_wait_for 30 grep -qs '"to":"STOP","reason":"PERCEPTION"' "$RESULTS/flyd.log" || true
_n="$(wc -l <"$RESULTS/timeline.txt")"
flyd_wait_frame $((_n + 30)) 60
flyd_event motion-start
canplayer -I "$RESULTS/input/motion.log"
flyd_event_after motion-end
_n="$(wc -l <"$RESULTS/timeline.txt")"
flyd_wait_frame $((_n + 20)) 60
flyd_stop
