#!/bin/sh
# One camera stops mid-run: the feeder writes nothing to the left camera for frames 20..49 (3 s
# at 10 fps; flyd's stale limit is 6 frames), then resumes. flyd must raise LEFT_CAMERA_STALE
# and fall back to its safe command, then recover to RUNNING. Empty road, so the only reason
# for a non-CLEAR command is the fault.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road --stop-camera left --at-frame 20 --resume-at 50
flyd_wait_frame 90 90
flyd_stop
