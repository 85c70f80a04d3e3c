#!/bin/sh
# The native runner (native.sh, for hosts that have vcan0 and v4l2loopback, no QEMU) run inside
# the guest, which has exactly such devices, on the vcan smoke scenario. The host checks the
# nested run's results in $RESULTS/native. Its markers stay in its own console.log.
set -eu
native.sh --script "$(command -v vcan_smoke.sh)" --results "$RESULTS/native" --timeout 60 \
    >/dev/null
