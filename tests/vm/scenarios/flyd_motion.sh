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
flyd_event motion-start
canplayer -I "$RESULTS/input/motion.log"
flyd_event_after motion-end
_n="$(wc -l <"$RESULTS/timeline.txt")"
flyd_wait_frame $((_n + 20)) 60
flyd_stop
