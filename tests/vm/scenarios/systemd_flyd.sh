#!/bin/sh
# flyd under a real systemd (issue 34): run by flyd-vm-scenario.service in the Debian 12 guest
# (tests/vm/systemd), with systemd as PID 1. The Debian package (scripts/package, in
# $RESULTS/input) is installed with apt; the configuration points flyd at the two loopback
# cameras and vcan0; flyd-feeder plays pedestrian-steps-in. Then, each step recorded for the
# host (tests/vm.rs):
#   install     apt install ./flyd_*.deb: the unit loaded, neither enabled nor started
#   start       systemctl start flyd returns once flyd sent READY=1 (Type=notify)
#   pedestrian  STOP on vcan0 (candump.log), the feeder past frame 90
#   journal     flyd logs natively to the journal (issue 45): `journalctl -u flyd -p err` on
#               the clean run to frame 55 (err-clean.json), then the right camera black from
#               frame 60 to 75 (the feeder's --black): `-p warning` (warnings.json) and a
#               match on a field of flyd's (FLYD_CAMERA=right: field-match.json)
#   security    systemd-analyze security flyd on the running unit
#   watchdog    flyd SIGSTOPped: systemd's watchdog kills it, Restart= starts it again
#               (NRestarts grows, a new MainPID), it warms up again and sends again
#   stop        systemctl stop flyd: SHUTDOWN status frame, exit status 0
#   upgrade     /etc/flyd/flyd.toml edited, flyd running, the package installed over itself:
#               the edit kept, flyd restarted on the "new" binary
#   remove      apt remove stops flyd (config kept); apt purge removes the conffiles
# A *.conf file in $RESULTS/input is installed as a drop-in for flyd.service first (the host
# passes FLYD_VM_SYSTEMD_DROPIN: e.g. WatchdogSec=0, to show that the scenario then fails).
set -eu
. "$(command -v flyd_common.sh)"

[ "$(cat /proc/1/comm)" = systemd ] || { echo "PID 1 is $(cat /proc/1/comm), not systemd" >&2; exit 1; }
mkdir -p /tmp/pkg
cp "$RESULTS"/input/flyd_*_amd64.deb /tmp/pkg/
deb="$(echo /tmp/pkg/flyd_*_amd64.deb)"

main_pid() { systemctl show -p MainPID --value flyd; }
restarts() { systemctl show -p NRestarts --value flyd; }

# --- install ------------------------------------------------------------------------------
apt-get install -y -q --no-install-recommends "$deb" >"$RESULTS/apt-install.log" 2>&1
vm_result installed "enabled=$(systemctl is-enabled flyd || true)" \
    "active=$(systemctl is-active flyd || true)" \
    "unit=$(systemctl show -p FragmentPath --value flyd)" \
    "version=$(dpkg-query -W -f='${Version}' flyd)"
for conf in "$RESULTS"/input/*.conf; do
    [ -f "$conf" ] || continue
    echo "drop-in for flyd.service: $conf" >&2
    mkdir -p /etc/systemd/system/flyd.service.d
    cp "$conf" /etc/systemd/system/flyd.service.d/
    systemctl daemon-reload
done

# --- configure: the VM configuration, pointing at the loopback cameras and vcan0 -------------
flyd_config
# Logs as the shipped configuration has them (format = "auto": the journal under systemd), not
# the other scenarios' JSON lines to a file.
sed -i 's/^format = "json"$/format = "auto"/' "$FLYD_DIR/flyd.toml"
grep -q '^format = "auto"$' "$FLYD_DIR/flyd.toml"
install -m 0644 "$FLYD_DIR/flyd.toml" /etc/flyd/flyd.toml
install -m 0644 "$FLYD_DIR/mock-rig-320x240.toml" /etc/flyd/mock-rig-320x240.toml
flyd check-config /etc/flyd/flyd.toml

flyd_candump
flyd_feeder pedestrian-steps-in --black right --at-frame 60 --resume-at 75
# flyd's stdout as journald stored it, across restarts: what the frame-counting helpers read.
journalctl -u flyd -f -o cat --no-pager >"$RESULTS/flyd.log" 2>&1 &
JOURNAL=$!

# --- start ----------------------------------------------------------------------------------
flyd_event flyd-started
systemctl start flyd
vm_result start "active=$(systemctl is-active flyd)" \
    "substate=$(systemctl show -p SubState --value flyd)" "pid=$(main_pid)"
systemctl show flyd >"$RESULTS/show-start.txt"
flyd_wait_running 90
flyd_go
flyd_wait_frame 55 60
# --- the journal: priorities and fields ------------------------------------------------------
journalctl -u flyd -p err -o json --no-pager >"$RESULTS/err-clean.json"
flyd_wait_frame 90 60
# The black camera's WARN is in the journal by now: the whole journal, then what -p warning
# and a field match list.
journalctl -u flyd -o json --no-pager >"$RESULTS/journal-at-90.json"
journalctl -u flyd -p warning -o json --no-pager >"$RESULTS/warnings.json"
journalctl -u flyd -o json --no-pager FLYD_CAMERA=right >"$RESULTS/field-match.json"
# The commands of systemd/README.md's Logs section, as documented: output and exit status.
doc_command() {
    _name="$1"
    shift
    _rc=0
    "$@" --no-pager >"$RESULTS/doc-$_name.txt" 2>&1 || _rc=$?
    echo "$_name $_rc" >>"$RESULTS/doc-commands.txt"
}
doc_command follow timeout 3 journalctl -u flyd -f
doc_command warning journalctl -u flyd -b -p warning
doc_command err journalctl -u flyd -b -p err
doc_command field journalctl -u flyd FLYD_CAMERA=right
doc_command thread journalctl -u flyd FLYD_THREAD=flyd-control -n 5
doc_command verbose journalctl -u flyd -o verbose -n 1

# --- security, on the running unit -----------------------------------------------------------
systemd-analyze security --no-pager flyd >"$RESULTS/security.txt" 2>&1

# --- watchdog ---------------------------------------------------------------------------------
pid="$(main_pid)"
before="$(restarts)"
flyd_event sigstop
# The feeder's latest frame can be well before the kill on a loaded host (CI saw 0.5 s): the
# kill itself is stamped with the realtime clock (coreutils date in this guest), the same
# clock as candump's and the feeder's.
stop_before="$(date +%s.%N)"
kill -STOP "$pid"
stop_after="$(date +%s.%N)"
vm_result sigstop "before=$stop_before" "after=$stop_after"
restarted() {
    [ "$(restarts)" -gt "$before" ] && [ "$(main_pid)" != 0 ] && [ "$(main_pid)" != "$pid" ] \
        && [ "$(systemctl is-active flyd)" = active ]
}
if ! vm_wait_for 60 restarted; then
    systemctl status --no-pager flyd >&2 || true
    vm_result watchdog "restarted=no" "nrestarts=$(restarts)"
    exit 1
fi
flyd_event restarted
vm_result watchdog "restarted=yes" "nrestarts_before=$before" "nrestarts=$(restarts)" \
    "old_pid=$pid" "new_pid=$(main_pid)" "result=$(systemctl show -p Result --value flyd)"
warmed_up_twice() { [ "$(grep -c 'running: warm-up done' "$RESULTS/flyd.log")" -ge 2 ]; }
vm_wait_for 90 warmed_up_twice
flyd_event running-again
_n="$(wc -l <"$RESULTS/timeline.txt")"
flyd_wait_frame $((_n + 20)) 60

# --- stop -----------------------------------------------------------------------------------
flyd_event sigterm
systemctl stop flyd
flyd_event_after flyd-exited
systemctl show flyd >"$RESULTS/show-stop.txt"
vm_result flyd "exit=$(systemctl show -p ExecMainStatus --value flyd)" \
    "code=$(systemctl show -p ExecMainCode --value flyd)" \
    "result=$(systemctl show -p Result --value flyd)" \
    "frames=$(wc -l <"$RESULTS/timeline.txt")" "can_lines=$(wc -l <"$RESULTS/candump.log")"

# --- upgrade over itself, running, with an edited configuration -------------------------------
echo "# edited on this vehicle (systemd_flyd scenario)" >>/etc/flyd/flyd.toml
flyd_event upgrade-start
systemctl start flyd
pid="$(main_pid)"
apt-get install -y -q --reinstall "$deb" >"$RESULTS/apt-upgrade.log" 2>&1
vm_result upgrade "kept=$(grep -c 'edited on this vehicle' /etc/flyd/flyd.toml)" \
    "dpkg_files=$(find /etc/flyd -name '*.dpkg-*' | wc -l)" \
    "active=$(systemctl is-active flyd)" \
    "restarted=$(if [ "$(main_pid)" != "$pid" ]; then echo yes; else echo no; fi)"

# --- removal ----------------------------------------------------------------------------------
apt-get remove -y -q flyd >"$RESULTS/apt-remove.log" 2>&1
vm_result remove "active=$(systemctl is-active flyd || true)" \
    "binary=$(if [ -e /usr/bin/flyd ]; then echo present; else echo gone; fi)" \
    "config=$(if [ -f /etc/flyd/flyd.toml ]; then echo kept; else echo gone; fi)" \
    "processes=$(pgrep -c -x flyd || true)"
apt-get purge -y -q flyd >>"$RESULTS/apt-remove.log" 2>&1
vm_result purge "conffiles_left=$(ls /etc/flyd/flyd.toml /etc/flyd/rig.toml 2>/dev/null | wc -l)"

journalctl -u flyd -o json --no-pager >"$RESULTS/journal.json"
kill "$JOURNAL" "$FEEDER" 2>/dev/null || true
sleep 0.2
kill "$CANDUMP" 2>/dev/null || true
wait "$CANDUMP" 2>/dev/null || true
tail -n 3 "$RESULTS/feeder.log"
