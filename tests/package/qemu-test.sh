#!/usr/bin/env bash
# Runs a foreign-architecture mavbond package (arm64, armhf) on this amd64 machine under
# qemu-user: extracts the .deb, starts its daemon with its own plugins (plugin_dir pointing into
# the extracted tree) and routes frames through it over UDP; mavbondctl (also the foreign
# binary) reads the status socket.
#
#   tests/package/qemu-test.sh build-deb/mavbond_VERSION_arm64.deb [arm64|armhf]
#
# Needs qemu-user-static and the package's runtime libraries for that architecture
# (libc6, libstdc++6, libyaml-cpp0.7 :arm64/:armhf): scripts/package installs the arm64 ones on
# this machine and runs the armhf test inside its armhf build chroot, which has them. qemu runs
# without -L: with libc6:ARCH installed the binaries use the real loader (PACKAGING-NOTES,
# pitfall 3). armhf runs on an emulated Cortex-A7 (QEMU_CPU, the Raspberry Pi 2's core, the
# oldest 32-bit Pi armhf supports), and must be refused by an ARMv6 core (Pi 1/Zero): Debian
# armhf is ARMv7. Nothing is installed; exit 0 when every check passes.
set -euo pipefail

DEB=$(realpath "${1:?usage: qemu-test.sh PACKAGE.deb [ARCH]}")
ARCH=${2:-$(dpkg-deb -f "$DEB" Architecture)}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
case "$ARCH" in
    arm64) QEMU=qemu-aarch64-static; ELF='ARM aarch64' ;;
    armhf) QEMU=qemu-arm-static; ELF='32-bit .*ARM, EABI5.*interpreter /lib/ld-linux-armhf\.so\.3'
           export QEMU_CPU=${QEMU_CPU:-cortex-a7} ;;
    *) echo "qemu-test: no qemu for $ARCH" >&2; exit 1 ;;
esac
command -v "$QEMU" >/dev/null || { echo "qemu-test: $QEMU missing (apt-get install qemu-user-static)" >&2; exit 1; }
MULTIARCH=$(dpkg-architecture -a"$ARCH" -qDEB_HOST_MULTIARCH 2>/dev/null)
WORK=$(mktemp -d /tmp/mavbond-qemu-test.XXXXXX)
ROOTFS=$WORK/root
PLUGINDIR=$ROOTFS/usr/lib/$MULTIARCH/mavbond/plugins
DAEMON_PID=
source "$HERE/checks.sh"
stop_daemon() {
    [ -n "$DAEMON_PID" ] || return 0
    kill -TERM "$DAEMON_PID" 2>/dev/null || true
    for _ in $(seq 100); do kill -0 "$DAEMON_PID" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$DAEMON_PID" 2>/dev/null || true
    wait "$DAEMON_PID" 2>/dev/null && DAEMON_RC=0 || DAEMON_RC=$?
    DAEMON_PID=
}
trap 'stop_daemon; rm -rf "$WORK"' EXIT

echo "--- $(basename "$DEB") under $QEMU ($($QEMU --version | head -1))${QEMU_CPU:+, CPU $QEMU_CPU}"
dpkg-deb -x "$DEB" "$ROOTFS"
show "the daemon is an $ARCH binary" sh -c "file -L '$ROOTFS/usr/bin/mavbond' | tee /dev/stderr | grep -q '$ELF'"
if [ "$ARCH" = armhf ]; then
    # The CPU choice is real: an ARMv6 core stops at the first ARMv7 instruction.
    check "an ARMv6 core (arm1176: Pi 1/Zero) is refused (SIGILL)" \
        sh -c "QEMU_CPU=arm1176 $QEMU '$ROOTFS/usr/bin/mavbond' --version; [ \$? -eq 132 ]"
fi
show "plugins in the package" ls "$PLUGINDIR"
show "mavbond --version under qemu" "$QEMU" "$ROOTFS/usr/bin/mavbond" --version
show "the shipped config checks" "$QEMU" "$ROOTFS/usr/bin/mavbond" --check-config -c "$ROOTFS/etc/mavbond/mavbond.yaml"
# The importer parses numbers (ports, rates, message ids) into the word size: on a 32-bit
# target a bound that fits 64 bits only goes wrong (tests/integration/test_import.py's files).
IMPORT_DATA=$HERE/../integration/data/mavlink-router
check "mavbond --import-mavlink-router companion.conf under qemu gives companion.yaml" \
    sh -c "cd '$IMPORT_DATA' && '$QEMU' '$ROOTFS/usr/bin/mavbond' --import-mavlink-router companion.conf \
           >'$WORK/import.yaml' && diff -u companion.yaml '$WORK/import.yaml'"

ports=$(python3 -c 'import socket
ss=[socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
[s.bind(("127.0.0.1", 0)) for s in ss]; print(*[s.getsockname()[1] for s in ss])')
read -r P_GCS P_R1 P_R2 <<<"$ports"
cat >"$WORK/bond.yaml" <<EOF
plugin_dir: $PLUGINDIR
status_socket: $WORK/status.sock
endpoints:
  - {name: gcs, type: udp, mode: server, address: 127.0.0.1:$P_GCS}
  - {name: radio1, type: udp, mode: server, address: 127.0.0.1:$P_R1, bond: air}
  - {name: radio2, type: udp, mode: server, address: 127.0.0.1:$P_R2, bond: air}
bonds:
  - {name: air, tx: active}
filters:
  - {plugin: linkswitch, bonds: [air]}
  - {plugin: dedup, bonds: [air]}
  - {plugin: stats, interval: 1s}
EOF
show "--check-config loads the $ARCH plugins" "$QEMU" "$ROOTFS/usr/bin/mavbond" --check-config -c "$WORK/bond.yaml"

"$QEMU" "$ROOTFS/usr/bin/mavbond" -c "$WORK/bond.yaml" >"$WORK/daemon.log" 2>&1 &
DAEMON_PID=$!
started=0
for _ in $(seq 300); do   # qemu start-up is slow on a loaded machine: up to 30 s
    grep -q "running with" "$WORK/daemon.log" && { started=1; break; }
    kill -0 "$DAEMON_PID" 2>/dev/null || break
    sleep 0.1
done
if [ $started -eq 1 ]; then
    ok "daemon started under qemu: $(grep -m1 'running with' "$WORK/daemon.log")"
    show "route frames through the $ARCH daemon and its plugins" \
        python3 "$HERE/route_check.py" bond "$P_GCS" "$P_R1" "$P_R2"
    show "mavbondctl ($ARCH) status" "$QEMU" "$ROOTFS/usr/bin/mavbondctl" -s "$WORK/status.sock" status
    stop_daemon
    if [ "$DAEMON_RC" -eq 0 ]; then ok "clean stop on SIGTERM"; else fail "exit $DAEMON_RC on SIGTERM"; fi
    echo "      daemon log:"; sed 's/^/      | /' "$WORK/daemon.log"
else
    fail "daemon did not start under qemu"; sed 's/^/      /' "$WORK/daemon.log"
fi

tally "qemu-test ($ARCH)"
