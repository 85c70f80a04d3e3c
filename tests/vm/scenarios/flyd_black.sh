#!/bin/sh
# One camera goes black mid-run: the feeder writes black YUYV frames (Y=16, U=V=128) to the
# right camera for frames 20..49 (3 s at 10 fps), then real frames again. Uniform windows
# "match" everywhere, so the flies alone would read a clear road: flyd must raise UNIFORM
# (CAMERA_ERROR), fall back to its safe command and recover to RUNNING. Empty road, so the only
# reason for a non-CLEAR command is the fault.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road --black right --at-frame 20 --resume-at 50
flyd_wait_frame 90 90
flyd_stop
