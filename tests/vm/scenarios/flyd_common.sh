# shellcheck shell=sh
# Helpers of the flyd scenarios (flyd_*.sh), shipped with `.bin` and sourced with
#   . "$(command -v flyd_common.sh)"
# They expect the host test to have given flyd, flyd-feeder, this file, and the inputs
# tests/vm/config/flyd-vm.toml and mock-rig-320x240.toml (in $RESULTS/input).
#
# Every helper leaves its evidence in $RESULTS for the host:
#   candump.log   candump -L of vcan0 for the whole run
#   flyd.log      flyd's JSON log (stdout) and its stderr
#   feeder.log    flyd-feeder's stderr; timeline.txt its per-frame timeline
#   events.txt    "NAME INDEX SECONDS" lines for the script's own actions (flyd_event): the
#                 feeder's latest frame at that moment (index and realtime from timeline.txt;
#                 "- -" before the first one); busybox date has no sub-second clock

FLYD_DIR="${TMPDIR:-/tmp}/flyd-vm.$$"
FLYD_GO="$FLYD_DIR/go"

# flyd_event NAME: records when a scenario action happened, in feeder frames: the feeder's
# latest complete timeline line (counted with wc: tail on a 9p file being appended can return
# a torn line).
flyd_event() {
    _n="$(wc -l <"$RESULTS/timeline.txt" 2>/dev/null || echo 0)"
    if [ "$_n" -gt 0 ]; then
        echo "$1 $(grep "^$((_n - 1)) " "$RESULTS/timeline.txt" | cut -d' ' -f1,2)" >>"$RESULTS/events.txt"
    else
        echo "$1 - -" >>"$RESULTS/events.txt"
    fi
}

# flyd_event_after NAME: like flyd_event for an action just done, but with a frame the feeder
# wrote after the action (the second one after the latest complete line: the first may have
# been under way), so that its time is no earlier than the action. flyd_event, taken before an
# action, gives a time no later than it.
flyd_event_after() {
    _n="$(wc -l <"$RESULTS/timeline.txt")"
    flyd_wait_frame $((_n + 1)) 30
    echo "$1 $(grep "^$((_n + 1)) " "$RESULTS/timeline.txt" | cut -d' ' -f1,2)" >>"$RESULTS/events.txt"
}

# flyd_config: writes $FLYD_DIR/flyd.toml for this machine's labelled cameras, with
# $FLYD_TOML_EXTRA (TOML tables a scenario adds) at its end.
flyd_config() {
    mkdir -p "$FLYD_DIR"
    cp "$RESULTS/input/mock-rig-320x240.toml" "$FLYD_DIR/"
    sed -e "s#@LEFT@#$FLYD_CAM_LEFT#" -e "s#@RIGHT@#$FLYD_CAM_RIGHT#" \
        "$RESULTS/input/flyd-vm.toml" >"$FLYD_DIR/flyd.toml"
    if [ -n "${FLYD_TOML_EXTRA:-}" ]; then
        printf '%s\n' "$FLYD_TOML_EXTRA" >>"$FLYD_DIR/flyd.toml"
    fi
}

# flyd_candump: candump -L of the bus to $RESULTS/candump.log, once it listens.
flyd_candump() {
    _before="$(vm_can_receivers "$FLYD_CAN")"
    # A 4 MB receive buffer (SO_RCVBUFFORCE as root): on a loaded host the emulated candump
    # can fall behind flyd's ~110 frames/s, and the default buffer then drops frames (seen as
    # an alive-counter jump in the log with no CAN error in flyd's).
    candump -r 4194304 -L "$FLYD_CAN" >"$RESULTS/candump.log" &
    CANDUMP=$!
    vm_wait_for 10 vm_can_receivers_above "$FLYD_CAN" "$_before"
}

# flyd_feeder SCENARIO [FEEDER ARGS...]: starts flyd-feeder at 320x240 and 10 fps (flyd-vm.toml
# says so too: a third of the scenarios' 30 fps, for the emulated CPUs), pre-rendered, in
# lead-in (the scenario's first frame) until flyd_go; returns once frames flow.
flyd_feeder() {
    _scenario="$1"
    shift
    flyd-feeder --left "$FLYD_CAM_LEFT" --right "$FLYD_CAM_RIGHT" --scenario "$_scenario" \
        --width 320 --height 240 --fps 10 --prerender --frames 0 --wait-for "$FLYD_GO" \
        --timeline "$RESULTS/timeline.txt" "$@" 2>"$RESULTS/feeder.log" &
    FEEDER=$!
    vm_wait_for 120 grep -qs 'first frame written' "$RESULTS/feeder.log"
}

# flyd_start: starts flyd on the config (JSON log to $RESULTS/flyd.log), with the arguments
# in $FLYD_ARGS (a scenario's, split on spaces); returns at once.
flyd_start() {
    # shellcheck disable=SC2086 # FLYD_ARGS is split on purpose
    flyd run --config "$FLYD_DIR/flyd.toml" ${FLYD_ARGS:-} >"$RESULTS/flyd.log" 2>&1 &
    FLYD=$!
    flyd_event flyd-started
}

# flyd_wait_running SECS: until flyd logs that its warm-up is done (state RUNNING).
flyd_wait_running() {
    vm_wait_for "$1" grep -qs 'running: warm-up done' "$RESULTS/flyd.log"
    flyd_event flyd-running
}

# flyd_launch SCENARIO [FEEDER ARGS...]: the common start of a flyd scenario: the config,
# candump, the feeder's lead-in, flyd started and RUNNING, then the scenario from frame 0.
flyd_launch() {
    flyd_config
    flyd_candump
    flyd_feeder "$@"
    flyd_start
    flyd_wait_running 90
    flyd_go
}

# flyd_go: the feeder leaves its lead-in and plays the scenario from frame 0.
flyd_go() {
    touch "$FLYD_GO"
    vm_wait_for 10 grep -qs 'playing' "$RESULTS/feeder.log"
}

# flyd_wait_frame N SECS: until the feeder has written scenario frame N.
flyd_wait_frame() {
    vm_wait_for "$2" grep -qs "^$1 " "$RESULTS/timeline.txt"
}

# flyd_stop: SIGTERM to flyd; records its exit code as @@RESULT name=flyd exit=N@@; stops the
# feeder and candump.
flyd_stop() {
    flyd_event sigterm
    kill -TERM "$FLYD"
    _code=0
    wait "$FLYD" || _code=$?
    flyd_event flyd-exited
    kill "$FEEDER" 2>/dev/null || true
    wait "$FEEDER" 2>/dev/null || true
    sleep 0.2
    kill "$CANDUMP" 2>/dev/null || true
    wait "$CANDUMP" 2>/dev/null || true
    vm_result flyd "exit=$_code" "frames=$(wc -l <"$RESULTS/timeline.txt")" \
        "can_lines=$(wc -l <"$RESULTS/candump.log")"
    tail -n 5 "$RESULTS/flyd.log"
    tail -n 3 "$RESULTS/feeder.log"
}
