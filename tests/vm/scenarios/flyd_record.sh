#!/bin/sh
# Recording through the real kernel stacks: the pedestrian steps in (hw-mock
# pedestrian-steps-in) in front of the two v4l2loopback cameras while flyd records
# (--record $RESULTS/drive.mcap, chunks uncompressed: zstd costs the emulated CPUs); SIGTERM at
# frame 60. The host replays the recording and compares its CAN frames with vcan0's.
set -eu
. "$(command -v flyd_common.sh)"
FLYD_TOML_EXTRA='[record]
compression = "none"'
FLYD_ARGS="--record $RESULTS/drive.mcap"
flyd_launch pedestrian-steps-in
flyd_wait_frame 60 60
flyd_stop
