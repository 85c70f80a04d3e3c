#!/bin/sh
# A camera with the wrong format: the feeder gives the right camera 160x120 YUYV (flyd asks for
# 320x240) and writes frames of that size. flyd must log a clear error naming the device, raise
# CAMERA_ERROR on the bus, keep running (safe command), and exit 0 on SIGTERM.
set -eu
. "$(command -v flyd_common.sh)"
flyd_config
flyd_candump
flyd_feeder pedestrian-steps-in --format right --as 160x120:YUYV
vm_result devices "left=$FLYD_CAM_LEFT" "right=$FLYD_CAM_RIGHT"
flyd_start
vm_wait_for 60 grep -qs 'camera error' "$RESULTS/flyd.log"
flyd_go
flyd_wait_frame 40 60
flyd_stop
