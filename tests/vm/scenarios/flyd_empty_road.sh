#!/bin/sh
# Empty road for the whole run (hw-mock empty-road): flyd must never send STOP and must report
# RUNNING. flyd warms up on the first scene; 60 frames (6 s at 10 fps) of the scenario; SIGTERM.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road
flyd_wait_frame 60 60
flyd_stop
