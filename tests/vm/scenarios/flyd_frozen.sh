#!/bin/sh
# One camera freezes mid-run: the feeder writes the right camera's frame 20 again and again
# until frame 49 (3 s at 10 fps; the driver stamps each with a fresh time), then real frames
# again. A frozen image keeps the population converged on the old scene: flyd must raise FROZEN
# (CAMERA_ERROR), fall back to its safe command and recover to RUNNING.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch empty-road --freeze right --at-frame 20 --resume-at 50
flyd_wait_frame 90 90
flyd_stop
