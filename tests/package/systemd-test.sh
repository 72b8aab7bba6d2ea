#!/usr/bin/env bash
# The amd64 package under a real systemd: a Debian bookworm container booted with
# systemd-nspawn (systemd as PID 1, its own network namespace), the package installed in it
# with apt. The unit (Type=notify) becomes active on the daemon's READY=1 and shows its
# STATUS= line; it starts from the shipped config and routes; `systemd-analyze security`
# is reported; a user in group mavbond runs mavbondctl status, one outside is refused; the
# conffile is edited while frames flow and `systemctl reload` applies it with none lost, the
# unit going through RELOADING=1 to READY=1 (systemd's debug log shows each notification);
# the journal carries the link events; a daemon frozen with SIGSTOP stops feeding the
# watchdog and systemd restarts it; `systemctl stop` ends it cleanly.
#
#   tests/package/systemd-test.sh build-deb/mavbond_VERSION_amd64.deb
#
# The container's tree (debootstrap minbase + systemd, dbus and the package's dependencies)
# is made once and kept in MAVBOND_CONTAINER_CACHE (default /var/cache/mavbond-tests/
# bookworm-systemd); each run boots a copy. As root; it installs systemd-container and
# debootstrap on the host when missing. Where this machine cannot boot a container it says
# why and counts one skip. Exit 0: all passed (or skipped).
set -euo pipefail

DEB=$(realpath "${1:?usage: systemd-test.sh PACKAGE.deb}")
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
CACHE=${MAVBOND_CONTAINER_CACHE:-/var/cache/mavbond-tests/bookworm-systemd}
CACHE_STAMP=$CACHE/.mavbond-container-v1
INCLUDE=systemd,systemd-sysv,dbus,libyaml-cpp0.7,adduser,procps,python3-minimal
CONF=/etc/mavbond/mavbond.yaml
WORK=$(mktemp -d /tmp/mavbond-systemd-test.XXXXXX)
ROOTFS=$WORK/root
NSPAWN_PID=
INIT=
MOUNTED_NSPAWN_TMPFS=no
source "$HERE/checks.sh"

[ "$(id -u)" -eq 0 ] || { echo "systemd-test: needs root" >&2; exit 1; }

cleanup() {
    if [ -n "$NSPAWN_PID" ] && kill -0 "$NSPAWN_PID" 2>/dev/null; then
        kill -TERM "$NSPAWN_PID" 2>/dev/null   # nspawn asks the container's systemd to halt
        for _ in $(seq 300); do kill -0 "$NSPAWN_PID" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$NSPAWN_PID" 2>/dev/null || true
    fi
    [ "$MOUNTED_NSPAWN_TMPFS" = yes ] && umount /run/systemd/nspawn 2>/dev/null
    rm -rf "$WORK"
}
trap cleanup EXIT

skip() {   # the machine cannot do it: why, and one skip in the tally
    echo "SKIP  $*"
    echo "systemd-test: $PASSED passed, $FAILED failed, 1 skipped"
    exit 0
}

in_container() {   # a command in the booted container: its namespaces, its root (-r: also
    # from inside a chroot, where entering the mount namespace alone keeps the chroot's), its PATH
    nsenter -t "$INIT" -m -u -i -n -p -r -w env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 "$@"
}

container_init() {   # the container's PID 1 as this machine numbers it: a descendant of nspawn
    local p queue=("$NSPAWN_PID")
    while [ ${#queue[@]} -gt 0 ]; do
        p=${queue[0]}
        queue=("${queue[@]:1}")
        if [ "$p" != "$NSPAWN_PID" ] && [ "$(cat "/proc/$p/comm" 2>/dev/null)" = systemd ] &&
           [ "$(awk '/^NSpid:/ {print $NF}' "/proc/$p/status" 2>/dev/null)" = 1 ]; then
            echo "$p"
            return 0
        fi
        # shellcheck disable=SC2207  # pids are words
        queue+=($(pgrep -P "$p" || true))
    done
    return 1
}

# --- the host's tools and the cached tree ------------------------------------------------
missing=()
command -v systemd-nspawn >/dev/null || missing+=(systemd-container)
command -v debootstrap >/dev/null || missing+=(debootstrap)
if [ ${#missing[@]} -gt 0 ]; then
    DEBIAN_FRONTEND=noninteractive apt-get install -q -y --no-install-recommends \
        -o DPkg::Lock::Timeout=600 "${missing[@]}" >"$WORK/apt.log" 2>&1 ||
        { cat "$WORK/apt.log"; skip "cannot install ${missing[*]} here"; }
fi
if [ ! -f "$CACHE_STAMP" ]; then
    say "debootstrap --variant=minbase --include=$INCLUDE bookworm $CACHE (once)"
    rm -rf "$CACHE.new"
    mkdir -p "$(dirname "$CACHE")"
    if ! debootstrap --variant=minbase --include="$INCLUDE" bookworm "$CACHE.new" \
            >"$WORK/debootstrap.log" 2>&1; then
        tail -n 20 "$WORK/debootstrap.log"
        skip "debootstrap failed (above)"
    fi
    rm -rf "$CACHE"
    mv "$CACHE.new" "$CACHE"
    touch "$CACHE_STAMP"
fi
cp -a "$CACHE" "$ROOTFS"
# Not in /tmp: the booted system mounts a tmpfs over it.
mkdir -p "$ROOTFS/srv/test"
cp "$DEB" "$ROOTFS/srv/test/mavbond.deb"
cp "$HERE/route_check.py" "$ROOTFS/srv/test/"

# --- boot --------------------------------------------------------------------------------
say "boot the container (systemd-nspawn -b, a private network)"
# nspawn keeps propagation mounts under /run/systemd/nspawn and refuses a host where that is
# not its own file system (../shared/design/REAL-PEERS-NOTES.md).
if ! mountpoint -q /run/systemd/nspawn; then
    mkdir -p /run/systemd/nspawn
    mount -t tmpfs tmpfs /run/systemd/nspawn && MOUNTED_NSPAWN_TMPFS=yes
fi
# Without a system bus on the host: --register=no --keep-unit.
systemd-nspawn --quiet --register=no --keep-unit --private-network -D "$ROOTFS" -b \
    >"$WORK/boot.log" 2>&1 </dev/null &
NSPAWN_PID=$!
for _ in $(seq 300); do
    INIT=$(container_init) && break
    kill -0 "$NSPAWN_PID" 2>/dev/null || break
    sleep 0.1
done
if [ -z "$INIT" ]; then
    sed 's/^/      /' "$WORK/boot.log"
    skip "systemd-nspawn could not boot a container on this machine (its output above)"
fi
# systemctl talks to PID 1 over /run/systemd/private, there once systemd has set up.
up=no
for _ in $(seq 300); do
    in_container test -S /run/systemd/private 2>/dev/null && { up=yes; break; }
    sleep 0.1
done
if [ $up = no ]; then
    sed 's/^/      /' "$WORK/boot.log"
    in_container ls /srv/test 2>&1 | sed 's/^/      /'
    skip "the container's systemd did not come up within 30 s here (its output above)"
fi
state=$(in_container timeout 60 systemctl is-system-running --wait 2>&1) || true
check "systemd is PID 1 and the system is up: $state" test "$state" = running

# --- install: the unit starts from the shipped config -------------------------------------
say "apt-get install ./mavbond.deb in the container"
check "apt-get install /srv/test/mavbond.deb" in_container apt-get install -q -y --no-install-recommends /srv/test/mavbond.deb
unit_is() {   # unit_is STATE: the unit reaches it within 10 s
    for _ in $(seq 100); do
        [ "$(in_container systemctl is-active mavbond)" = "$1" ] && return 0
        sleep 0.1
    done
    in_container systemctl status --no-pager mavbond
    return 1
}
check "systemctl is-active mavbond: active (postinst started it)" unit_is active
journal() { in_container journalctl -u mavbond --no-pager -o cat; }   # the unit's messages
prop() { in_container systemctl show -p "$1" --value mavbond; }
notify_ready() {   # Type=notify: active means systemd had READY=1; the STATUS= line is there
    local t s
    t=$(prop Type)
    s=$(prop StatusText)
    echo "Type=$t StatusText=$s"
    [ "$t" = notify ] && grep -q "2 endpoints, [0-9]* frames routed" <<<"$s"
}
show "active via the daemon's READY=1, with its STATUS= line" notify_ready
running_log() { journal | grep -m1 "running with"; }
show "the journal: it runs the shipped config" running_log
show "a frame routed between the shipped endpoints (UDP 14550 <-> 14540)" \
    in_container python3 /srv/test/route_check.py pair 14550 14540
security() {
    in_container systemd-analyze security --no-pager mavbond >"$WORK/security.out" 2>&1 || true
    tail -n 1 "$WORK/security.out"
    grep -q "Overall exposure level for mavbond.service" "$WORK/security.out"
}
show "systemd-analyze security mavbond" security

say "mavbondctl status without sudo"
in_container useradd --create-home pilot
in_container useradd --create-home visitor
in_container adduser --quiet pilot mavbond
status_as() { in_container runuser -u "$1" -- mavbondctl status; }
refused_as() {   # fails, and names the group that would do
    local out
    out=$(status_as "$1" 2>&1) && { echo "$out"; return 1; }
    echo "$out"
    grep -q "adduser" <<<"$out"
}
show "pilot (in group mavbond) runs mavbondctl status" status_as pilot
show "visitor (not in it) is refused, with the group named" refused_as visitor

# --- reload while frames flow -------------------------------------------------------------
say "edit the conffile, systemctl reload while frames flow"
cat >>"$ROOTFS$CONF" <<'EOF'
# added by systemd-test: a bond of two radios
  - {name: radio1, type: udp, mode: server, address: 127.0.0.1:14601, bond: air}
  - {name: radio2, type: udp, mode: server, address: 127.0.0.1:14602, bond: air}
bonds:
  - {name: air, tx: broadcast}
filters:
  - {plugin: dedup, bonds: [air]}
  - {plugin: stats}
link_events:
  silent_after: 1s
EOF
check "mavbond --check-config on the edited conffile" in_container mavbond --check-config
main_pid() { in_container systemctl show -p MainPID --value mavbond; }
pid_before=$(main_pid)
# systemd's debug log names every notification it gets and every state the unit enters.
check "systemd-analyze log-level debug" in_container systemd-analyze log-level debug
in_container python3 /srv/test/route_check.py stream 14550 14540 4 >"$WORK/stream.out" 2>&1 &
stream_pid=$!
sleep 1.5
check "systemctl reload mavbond" in_container systemctl reload mavbond
stream_rc=0
wait "$stream_pid" || stream_rc=$?
sed 's/^/      /' "$WORK/stream.out"
check "no frame lost or doubled across the reload" test "$stream_rc" -eq 0
reloaded() { journal | grep "reloaded: "; }
show "the journal: the reload took the edit" reloaded
check "still active" unit_is active
check "the same process (MainPID $pid_before)" test "$(main_pid)" = "$pid_before"
through_reloading() {   # RELOADING=1 (with MONOTONIC_USEC) and READY=1 after it, from the daemon
    local j
    j=$(journal | grep -E "Got notification message from PID $pid_before \((RELOADING|READY)=1" || true)
    echo "$j"
    grep -q "(RELOADING=1, MONOTONIC_USEC=[0-9]*, STATUS=reloading)" <<<"$j" &&
        grep -A100 "RELOADING=1" <<<"$j" | grep -q "(READY=1, STATUS=bond air: "
}
show "the unit went through the daemon's RELOADING=1 to its READY=1" through_reloading
reload_states() { journal | grep -E "mavbond.service: Changed (running -> reload|reload -> running)"; }
show "systemd's view: running -> reload -> running" reload_states
status_after() { prop StatusText; prop StatusText | grep -q "bond air: "; }
show "the STATUS= line names the new bond" status_after

say "link events in the journal"
show "a frame over both radios of the bond, delivered once" \
    in_container python3 /srv/test/route_check.py bond 14550 14601 14602
sleep 2   # both radios silent for over silent_after
link_events() {
    local j
    j=$(journal | grep "link event: " || true)
    echo "$j"
    # The direction is the side's own: this one hears the vehicle (1/1) through the bond.
    grep -q "link radio1 downlink up (bond air" <<<"$j" &&
        grep -q "link radio2 downlink lost (bond air" <<<"$j"
}
show "the journal: link radio1 downlink up, link radio2 downlink lost" link_events

# --- the watchdog: a frozen daemon is restarted ------------------------------------------
say "SIGSTOP the daemon: the loop stops feeding WatchdogSec, systemd restarts it"
check "WatchdogSec=10s" test "$(prop WatchdogUSec)" = 10s
frozen=$(main_pid)
restarts_before=$(prop NRestarts)
in_container kill -STOP "$frozen"
restarted() {   # a new main process, active (watchdog 10 s + RestartSec 2 s + start), <= 60 s
    local p
    for _ in $(seq 600); do
        p=$(main_pid)
        if [ "$p" != "$frozen" ] && [ "$p" != 0 ] && [ "$(in_container systemctl is-active mavbond)" = active ]; then
            echo "MainPID $frozen -> $p, NRestarts $restarts_before -> $(prop NRestarts)"
            return 0
        fi
        sleep 0.1
    done
    in_container systemctl status --no-pager mavbond
    return 1
}
show "restarted after the watchdog timeout" restarted
watchdog_log() {
    local j
    j=$(journal | grep -E "Watchdog timeout|Failed with result 'watchdog'" || true)
    echo "$j"
    grep -q "Watchdog timeout" <<<"$j" && grep -q "Failed with result 'watchdog'" <<<"$j"
}
show "the journal: the watchdog did it" watchdog_log
check "systemd-analyze log-level info" in_container systemd-analyze log-level info

# --- stop ---------------------------------------------------------------------------------
say "systemctl stop"
check "systemctl stop mavbond" in_container systemctl stop mavbond
stopped_clean() {
    local r
    r=$(in_container systemctl show -p Result -p ExecMainStatus -p ActiveState mavbond | tr '\n' ' ')
    echo "$r"
    grep -q "Result=success" <<<"$r" && grep -q "ExecMainStatus=0" <<<"$r" &&
        grep -q "ActiveState=inactive" <<<"$r"
}
show "stopped cleanly" stopped_clean
exit_line() { journal | tail -n 3; }
show "the journal's last lines" exit_line

tally systemd-test
