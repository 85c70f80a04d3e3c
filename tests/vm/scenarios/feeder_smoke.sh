#!/bin/sh
# flyd-feeder smoke: the feeder pre-renders pedestrian-steps-in at 320x240 and plays it into both
# loopback cameras at 30 fps; v4l2-smoke grabs frames from each capture side. The host checks
# the bytes against its own rendering of the scenario (each grabbed frame is one of the feeder's
# frames for that camera, in increasing order) and the timeline's pace.
set -eu
frames=8
flyd-feeder --left "$FLYD_CAM_LEFT" --right "$FLYD_CAM_RIGHT" --scenario pedestrian-steps-in \
    --width 320 --height 240 --prerender --frames 0 --timeline "$RESULTS/timeline.txt" \
    2>"$RESULTS/feeder.log" &
feeder=$!
vm_wait_for 120 grep -qs 'first frame written' "$RESULTS/feeder.log"
for cam in 0 1; do
    if [ "$cam" = 0 ]; then dev="$FLYD_CAM_LEFT"; else dev="$FLYD_CAM_RIGHT"; fi
    v4l2-smoke grab "$dev" "$frames" "$RESULTS/grab$cam.yuyv" 2>>"$RESULTS/grab.log" \
        || { cat "$RESULTS/grab.log"; exit 1; }
done
sleep 2
kill "$feeder"
wait "$feeder" 2>/dev/null || true
cat "$RESULTS/feeder.log" "$RESULTS/grab.log"
vm_result feeder "frames=$frames" "written=$(wc -l <"$RESULTS/timeline.txt")"
