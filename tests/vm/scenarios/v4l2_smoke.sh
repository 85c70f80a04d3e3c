#!/bin/sh
# v4l2loopback smoke: on each of the two loopback cameras, v4l2-smoke writes YUYV 64x48 test
# frames to the output side (VIDIOC_S_FMT + write) while v4l2-smoke mmap-streams the capture
# side, checks every frame and saves them to $RESULTS for the host to check again.
set -eu
frames=5
for cam in 0 1; do
    if [ "$cam" = 0 ]; then dev="$FLYD_CAM_LEFT"; else dev="$FLYD_CAM_RIGHT"; fi
    # Up to 60 s of frames at 25 fps, however slow the emulation; killed once captured.
    v4l2-smoke produce "$dev" "$cam" 1500 25 2>"$RESULTS/produce$cam.log" &
    producer=$!
    vm_wait_for 20 grep -qs 'first frame written' "$RESULTS/produce$cam.log"
    v4l2-smoke capture "$dev" "$cam" "$frames" "$RESULTS/capture$cam.yuyv" \
        2>"$RESULTS/capture$cam.log" || { cat "$RESULTS/capture$cam.log"; exit 1; }
    kill "$producer"
    wait "$producer" 2>/dev/null || true
    cat "$RESULTS/produce$cam.log" "$RESULTS/capture$cam.log"
    vm_result "camera$cam" "device=$dev" "frames=$frames"
done
