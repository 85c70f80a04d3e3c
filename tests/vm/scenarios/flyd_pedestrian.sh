#!/bin/sh
# Pedestrian steps in (hw-mock pedestrian-steps-in: empty road, then a pedestrian 4 m ahead at
# frame 30), played by flyd-feeder into the two loopback cameras, seen by the release flyd
# through V4L2, decided on, sent on vcan0. flyd starts and warms up on the empty first scene;
# the scenario plays once flyd is RUNNING; at frame 90 (60 frames, 6 s at 10 fps, after the
# pedestrian appeared), SIGTERM.
set -eu
. "$(command -v flyd_common.sh)"
flyd_launch pedestrian-steps-in
flyd_wait_frame 90 60
flyd_stop
