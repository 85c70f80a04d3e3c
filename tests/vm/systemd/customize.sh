#!/bin/sh
# mmdebstrap customize hook of rootfs.sh: $1 is the new root, $2 this directory. Makes the
# system boot straight to the scenario: no login prompts or timers, a fixed machine id (not a
# first boot), and flyd-vm-scenario.service, which runs the scenario and powers off.
set -eu
root="$1"
here="$2"
echo flyd-vm >"$root/etc/hostname"
# A machine id: no first-boot preset run (which would enable units on its own).
echo 5f1a7c0e2b9d4e6f8a3c1d2e4f6a8b0c >"$root/etc/machine-id"
ln -sf /lib/systemd/system/multi-user.target "$root/etc/systemd/system/default.target"
# Nothing on the console but the scenario's markers and systemd's errors; no periodic jobs.
for unit in serial-getty@ttyS0.service getty@tty1.service getty.target \
    apt-daily.timer apt-daily-upgrade.timer dpkg-db-backup.timer fstrim.timer \
    e2scrub_all.timer e2scrub_reap.service systemd-timesyncd.service; do
    ln -sf /dev/null "$root/etc/systemd/system/$unit"
done
install -m 0755 "$here/flyd-vm-scenario" "$root/usr/local/sbin/flyd-vm-scenario"
install -m 0644 "$here/flyd-vm-scenario.service" \
    "$root/etc/systemd/system/flyd-vm-scenario.service"
mkdir -p "$root/etc/systemd/system/multi-user.target.wants" "$root/results" \
    "$root/lib/flyd-vm"
ln -sf ../flyd-vm-scenario.service \
    "$root/etc/systemd/system/multi-user.target.wants/flyd-vm-scenario.service"
