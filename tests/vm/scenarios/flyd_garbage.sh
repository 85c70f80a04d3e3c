#!/bin/sh
# One camera delivers noise mid-run: the feeder writes random bytes of the right length to the
# right camera for frames 20..49 (3 s at 10 fps), then real frames again. The frames are valid
# YUYV, so no capture error: flyd must notice that the stereo pair matches nowhere (perception
# blind, CAMERA_ERROR), fall back to its safe command, and recover to RUNNING. Empty road, so
# the only reason for a non-CLEAR command is the fault.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road --garbage right --at-frame 20 --resume-at 50
flyd_wait_frame 90 90
flyd_stop
