#!/usr/bin/env bash
# Installs the mavbond .deb for this machine's architecture (as root), checks every file lands
# where it should, runs the installed daemon with the installed config and with the installed
# plugins, edits the conffile, reinstalls (the edit survives) and purges (everything goes).
# Given an apt repository (scripts/apt-repo) too, it then installs from it the way a user does
# (its key, one sources line), edits the conffile, upgrades to a newer version added to a copy
# of the repository (the same package repacked with a higher version), and purges.
#
#   tests/package/install-test.sh build-deb/mavbond_VERSION_amd64.deb [REPOSITORY]
#
# It leaves the machine as it found it: the package is purged on any exit. systemd is not
# needed (postinst only enables the unit when systemd is not running); the unit is checked
# with systemd-analyze verify and security, and the daemon is run the way the unit runs it:
# --check-config first, then as the package's system user mavbond in the dialout group. A user
# in group mavbond reads its status socket; one outside is refused. Exit 0: all passed.
set -euo pipefail

DEB=$(realpath "${1:?usage: install-test.sh PACKAGE.deb [REPOSITORY]}")
REPO=${2:+$(realpath "$2")}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
MULTIARCH=$(dpkg-architecture -qDEB_HOST_MULTIARCH)
PLUGINDIR=/usr/lib/$MULTIARCH/mavbond/plugins
CONF=/etc/mavbond/mavbond.yaml
UNIT=/lib/systemd/system/mavbond.service
RUN_AS=(setpriv --reuid=mavbond --regid=mavbond --groups=dialout --inh-caps=-all --no-new-privs)
READER=mavbond-install-test   # a login user made for the status socket checks, then removed
APT=(apt-get -q -y --no-install-recommends -o DPkg::Lock::Timeout=600)
export DEBIAN_FRONTEND=noninteractive
WORK=$(mktemp -d /tmp/mavbond-install-test.XXXXXX)
chmod 755 "$WORK"
DAEMON_PID=
source "$HERE/checks.sh"

[ "$(id -u)" -eq 0 ] || { echo "install-test: needs root (it installs the package)" >&2; exit 1; }
[ "$(dpkg-deb -f "$DEB" Architecture)" = "$(dpkg --print-architecture)" ] ||
    { echo "install-test: $DEB is not for $(dpkg --print-architecture)" >&2; exit 1; }

unexpected_files() {   # files (not directories) of the package outside its own places
    dpkg -L mavbond | while read -r f; do [ -d "$f" ] || echo "$f"; done |
        grep -v -E "^/(etc/mavbond/|lib/systemd/system/mavbond\.service$|usr/bin/mavbond(ctl)?$|usr/lib/$MULTIARCH/mavbond/plugins/[a-z]+\.so$|usr/share/doc/mavbond/|usr/share/man/man[158]/mavbond|usr/lib/sysctl\.d/60-mavbond\.conf$)" || true
}
verify_unit() {   # systemd-analyze verify prints nothing for a clean unit
    local out
    out=$(systemd-analyze verify "$UNIT" 2>&1)
    echo "$out"
    [ -z "$out" ]
}
list_plugins() {
    mavbondctl status --json | python3 -c 'import json, sys
names = sorted(f["plugin"] for f in json.load(sys.stdin)["filters"])
print(*names)
sys.exit(names != ["dedup", "linkswitch", "stats"])'
}
counters_ok() {
    mavbondctl status --json | python3 -c 'import json, sys
e = {x["name"]: x for x in json.load(sys.stdin)["endpoints"]}
print({n: (x["rx_frames"], x["tx_frames"]) for n, x in e.items()})
sys.exit(not (e["gcs"]["rx_frames"] >= 2 and e["autopilot"]["rx_frames"] >= 1))'
}
# The conffile edit that reinstalls and upgrades must keep.
edit_conffile() {
    sed -i 's/^log_level: info$/log_level: debug   # edited by install-test/' "$CONF"
    edit_kept
}
edit_kept() { grep -q 'edited by install-test' "$CONF"; }
no_dpkg_leftovers() {   # prints what dpkg left beside the conffile, if anything
    local left
    left=$(ls /etc/mavbond/*.dpkg-* 2>/dev/null || true)
    echo "$left"
    [ -z "$left" ]
}
installed() { dpkg-query -W -f='${Status}' mavbond 2>/dev/null | grep -q 'install ok installed'; }
known() { dpkg-query -W -f='${Status}' mavbond >/dev/null 2>&1 &&
          ! dpkg-query -W -f='${Status}' mavbond | grep -q 'not-installed'; }

stop_daemon() {
    if [ -n "$DAEMON_PID" ] && kill -0 "$DAEMON_PID" 2>/dev/null; then
        kill -TERM "$DAEMON_PID"
        for _ in $(seq 50); do kill -0 "$DAEMON_PID" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$DAEMON_PID" 2>/dev/null || true
    fi
    if [ -n "$DAEMON_PID" ]; then
        wait "$DAEMON_PID" 2>/dev/null && DAEMON_RC=0 || DAEMON_RC=$?
    fi
    DAEMON_PID=
}
cleanup() {
    stop_daemon
    if known; then "${APT[@]}" purge mavbond >/dev/null 2>&1 || dpkg --purge mavbond >/dev/null 2>&1 || true; fi
    rm -f "$REPO_LIST" /var/lib/apt/lists/*"$(basename "$WORK")"*
    rm -rf /run/mavbond "$WORK"
    if getent passwd "$READER" >/dev/null; then userdel "$READER" 2>/dev/null || true; fi
    # The system user stays after a purge (Debian practice: files it owned may remain), but
    # this machine had none before the test.
    if [ "$HAD_USER" = no ] && getent passwd mavbond >/dev/null; then
        userdel mavbond 2>/dev/null || true
        groupdel mavbond 2>/dev/null || true
    fi
}
HAD_USER=$(getent passwd mavbond >/dev/null && echo yes || echo no)
REPO_LIST=/etc/apt/sources.list.d/mavbond-install-test.list
trap cleanup EXIT

# Starts the installed daemon the way the unit does, waits until it logs "running".
start_daemon() {   # start_daemon CONFIG
    "${RUN_AS[@]}" /usr/bin/mavbond --check-config -c "$1" >"$WORK/check.out" 2>&1 ||
        { fail "mavbond --check-config -c $1"; cat "$WORK/check.out"; return 1; }
    ok "mavbond --check-config -c $1: $(cat "$WORK/check.out")"
    # Emptied here, not by the background job's redirection: that one truncates only once the
    # child runs, and the loop below could first read the previous daemon's "running with".
    : >"$WORK/daemon.log"
    "${RUN_AS[@]}" /usr/bin/mavbond -c "$1" >>"$WORK/daemon.log" 2>&1 &
    DAEMON_PID=$!
    for _ in $(seq 100); do
        grep -q "running with" "$WORK/daemon.log" && { ok "daemon running: $(grep -m1 'running with' "$WORK/daemon.log")"; return 0; }
        kill -0 "$DAEMON_PID" 2>/dev/null || break
        sleep 0.1
    done
    fail "daemon did not start with $1"; sed 's/^/      /' "$WORK/daemon.log"; stop_daemon; return 1
}
port_free() { ! ss -Hlun "sport = :$1" | grep -q .; }

# ----------------------------------------------------------------------------------------
if known; then
    echo "install-test: mavbond is already installed here; purge it first (apt-get purge mavbond)" >&2
    exit 1
fi
"${APT[@]}" install procps iproute2 util-linux man-db >/dev/null 2>&1 || true

say "install $(basename "$DEB")"
check "apt-get install ./$(basename "$DEB")" "${APT[@]}" install "$DEB"
installed || { echo "install-test: the package did not install" >&2; exit 1; }

say "files"
for f in /usr/bin/mavbond /usr/bin/mavbondctl; do
    check "$f is an executable" test -x "$f"
done
for p in dedup linkswitch stats; do
    check "plugin $PLUGINDIR/$p.so" test -f "$PLUGINDIR/$p.so"
done
check "$CONF is a conffile" sh -c "dpkg-query -W -f='\${Conffiles}' mavbond | grep -q ' $CONF '"
for f in $UNIT /usr/share/doc/mavbond/examples/air-side.yaml \
         /usr/share/doc/mavbond/examples/ground-side.yaml /usr/share/doc/mavbond/copyright \
         /usr/share/man/man8/mavbond.8.gz /usr/share/man/man1/mavbondctl.1.gz \
         /usr/share/man/man5/mavbond.yaml.5.gz; do
    check "$f" test -f "$f"
done
check "man -w mavbond.yaml" man -w 5 mavbond.yaml
check "/usr/lib/sysctl.d/60-mavbond.conf" test -f /usr/lib/sysctl.d/60-mavbond.conf
rmem_raised() {   # postinst applied the file, or this machine lets nobody set the limit (a container)
    local want have
    want=$(sed -n 's/^net.core.rmem_max *= *//p' /usr/lib/sysctl.d/60-mavbond.conf)
    have=$(sysctl -n net.core.rmem_max)
    [ "$have" -ge "$want" ] || ! sysctl -q -w "net.core.rmem_max=$have" 2>/dev/null
}
check "postinst raised net.core.rmem_max to the file's value" rmem_raised
unit_programs_provided() {   # every program the unit runs comes from mavbond or a dependency
    local deps prog owner ok=0
    deps=$(dpkg-query -W -f='${Depends}' mavbond)
    for prog in $(sed -n 's/^Exec[A-Za-z]*=[-@!+]*\(\/[^ ]*\).*/\1/p' "$UNIT" | sort -u); do
        owner=$(dpkg -S "$prog" 2>/dev/null | head -1 | cut -d: -f1)
        if [ -z "$owner" ] || { [ "$owner" != mavbond ] && ! echo "$deps" | grep -qw -- "$owner"; }; then
            echo "$prog: from '${owner:-no package}', not a dependency of mavbond"; ok=1
        else
            echo "$prog: $owner"
        fi
    done
    return $ok
}
system_user_ok() {   # postinst's user: a system account, no login, group mavbond
    local entry
    entry=$(getent passwd mavbond) || { echo "no user mavbond"; return 1; }
    echo "$entry"
    getent group mavbond
    [ "$(id -u mavbond)" -lt 1000 ] && [ "$(id -gn mavbond)" = mavbond ] &&
        case "$entry" in *:/nonexistent:/usr/sbin/nologin) ;; *) return 1 ;; esac
}
show "postinst created the system user and group mavbond" system_user_ok
check "no file outside the expected places" test -z "$(unexpected_files)"
check "the shipped config opens no serial port" sh -c "! grep -E '^[^#]*type: *uart' $CONF"
check "postinst enabled the unit" test -L /etc/systemd/system/multi-user.target.wants/mavbond.service
check "mavbond --version" /usr/bin/mavbond --version

say "systemd unit"
show "systemd-analyze verify $UNIT (no output)" verify_unit
show "the programs the unit runs come with mavbond or its dependencies" unit_programs_provided
exposure=$(systemd-analyze security --offline=yes "$UNIT" 2>/dev/null | sed -n 's/.*Overall exposure level for mavbond.service: \([0-9.]*\).*/\1/p')
check "systemd-analyze security: exposure $exposure (<= 2.0)" awk -v e="$exposure" 'BEGIN { exit !(e != "" && e <= 2.0) }'
for k in 'DynamicUser=yes' 'SupplementaryGroups=dialout' "ExecStartPre=/usr/bin/mavbond --check-config -c $CONF" \
         'Restart=on-failure' 'RuntimeDirectory=mavbond' 'NoNewPrivileges=yes' 'ProtectSystem=strict' \
         'ProtectHome=yes' 'PrivateTmp=yes' 'RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6' \
         'Type=notify' 'WatchdogSec=10s'; do
    check "unit: $k" grep -qxF "$k" "$UNIT"
done

say "installed daemon, installed config ($CONF)"
mkdir -p /run/mavbond && chown mavbond:mavbond /run/mavbond   # what RuntimeDirectory= does
useradd --no-create-home --shell /usr/sbin/nologin "$READER"
status_as() {   # status_as USER: mavbondctl status as USER with its groups from /etc/group
    setpriv --reuid="$1" --regid="$(id -g "$1")" --init-groups --inh-caps=-all mavbondctl status
}
refused_as() {   # refused_as USER: mavbondctl status fails and says which group would do
    local out
    out=$(status_as "$1" 2>&1) && { echo "$out"; return 1; }
    echo "$out"
    grep -q "adduser" <<<"$out"
}
if port_free 14550 && port_free 14540; then
    if start_daemon "$CONF"; then
        show "route a frame between the shipped endpoints (UDP 14550 <-> 14540)" \
            python3 "$HERE/route_check.py" pair 14550 14540
        show "mavbondctl status" mavbondctl status
        show "mavbondctl status --json: the frames were counted" counters_ok
        sock_mode=$(stat -c '%a %G' /run/mavbond/status.sock)
        check "status socket: mode and group '$sock_mode' are '660 mavbond'" test "$sock_mode" = "660 mavbond"
        show "a user outside group mavbond is refused, with the group named" refused_as "$READER"
        usermod -a -G mavbond "$READER"
        show "a user in group mavbond runs mavbondctl status without sudo" status_as "$READER"
        stop_daemon
        check "clean stop on SIGTERM (exit $DAEMON_RC)" test "$DAEMON_RC" -eq 0
        check "status socket removed at exit" test ! -e /run/mavbond/status.sock
    fi
else
    fail "UDP 14550 or 14540 is in use on this machine: cannot run the shipped config as is"
fi

say "installed daemon, installed plugins (default plugin_dir)"
ports=$(python3 -c 'import socket
ss=[socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
[s.bind(("127.0.0.1", 0)) for s in ss]; print(*[s.getsockname()[1] for s in ss])')
read -r P_GCS P_R1 P_R2 <<<"$ports"
cat >"$WORK/bond.yaml" <<EOF
status_socket: /run/mavbond/status.sock
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
chmod 644 "$WORK/bond.yaml"
if start_daemon "$WORK/bond.yaml"; then
    show "plugins loaded from $PLUGINDIR" list_plugins
    show "route frames through dedup/linkswitch/stats" python3 "$HERE/route_check.py" bond "$P_GCS" "$P_R1" "$P_R2"
    show "mavbondctl status" mavbondctl status
    stop_daemon
    check "clean stop (exit $DAEMON_RC)" test "$DAEMON_RC" -eq 0
fi
# The examples' signed bond reads /etc/mavbond/bond.key: made as a user makes it.
check "mavbondctl keygen /etc/mavbond/bond.key" mavbondctl keygen /etc/mavbond/bond.key
check "the key is the service user's, mode 0600" \
    test "$(stat -c %U:%a /etc/mavbond/bond.key)" = mavbond:600
check "keygen never overwrites a key" sh -c "! mavbondctl keygen /etc/mavbond/bond.key"
for ex in /usr/share/doc/mavbond/examples/*.yaml; do
    check "mavbond --check-config $ex (its filters load from $PLUGINDIR)" "${RUN_AS[@]}" /usr/bin/mavbond --check-config -c "$ex"
done
rm -f /etc/mavbond/bond.key  # the user's file: a purge leaves it (and /etc/mavbond with it)

say "conffile: edit, reinstall, purge"
check "conffile edited" edit_conffile
check "reinstall (apt-get install --reinstall)" "${APT[@]}" install --reinstall "$DEB"
check "the edit survives the reinstall" edit_kept
check "no .dpkg-new/.dpkg-dist left" no_dpkg_leftovers
check "dpkg -i over it (non-interactive)" dpkg -i --force-confdef --force-confold "$DEB"
check "the edit survives dpkg -i" edit_kept
check "mavbond --check-config on the edited conffile" /usr/bin/mavbond --check-config
check "apt-get purge mavbond" "${APT[@]}" purge mavbond
check "package gone" sh -c "! dpkg-query -W -f='\${Status}' mavbond 2>/dev/null | grep -q 'install ok installed'"
check "/etc/mavbond gone" test ! -e /etc/mavbond
check "/usr/bin/mavbond gone" test ! -e /usr/bin/mavbond
check "$PLUGINDIR gone" test ! -e "$PLUGINDIR"
check "unit and its enablement gone" sh -c "test ! -e $UNIT && test ! -L /etc/systemd/system/multi-user.target.wants/mavbond.service"

if [ -n "$REPO" ]; then
    say "apt repository: key and sources line, install, edit, upgrade, purge"
    cp -a "$REPO" "$WORK/repo"   # the newer version goes into a copy
    VERSION=$(dpkg-deb -f "$DEB" Version)
    NEWER=$VERSION+repotest1
    repo_update() {   # apt-get update of the repository's sources line only: clean or false
        apt-get -q update -o Dir::Etc::sourcelist="$REPO_LIST" -o Dir::Etc::sourceparts=- \
            -o APT::Get::List-Cleanup=0 >"$WORK/update.out" 2>&1
        local rc=$?
        cat "$WORK/update.out"
        [ $rc -eq 0 ] && ! grep -q '^[WE]:' "$WORK/update.out"
    }
    refused_without_key() { ! repo_update && grep -q NO_PUBKEY "$WORK/update.out"; }
    candidate_is() {
        apt-cache policy mavbond >"$WORK/policy.out"
        cat "$WORK/policy.out"
        grep -q "Candidate: $1\$" "$WORK/policy.out"
    }
    version_installed() { test "$(dpkg-query -W -f='${Version}' mavbond)" = "$1"; }
    purged() { ! installed && test ! -e /etc/mavbond; }
    echo "deb file:$WORK/repo bookworm main" > "$REPO_LIST"
    show "apt refuses the repository without its key" refused_without_key
    echo "deb [signed-by=$WORK/repo/mavbond-archive-keyring.gpg] file:$WORK/repo bookworm main" > "$REPO_LIST"
    show "apt-get update with the repository's key" repo_update
    check "the candidate is $VERSION, from the repository" candidate_is "$VERSION"
    check "apt-get install mavbond" "${APT[@]}" install mavbond
    check "installed: $VERSION" version_installed "$VERSION"
    check "conffile edited" edit_conffile
    dpkg-deb -R "$DEB" "$WORK/newer"
    sed -i "s/^Version: .*/Version: $NEWER/" "$WORK/newer/DEBIAN/control"
    check "a newer package ($NEWER)" dpkg-deb --root-owner-group -b "$WORK/newer" "$WORK/mavbond_${NEWER}_$(dpkg --print-architecture).deb"
    check "scripts/apt-repo adds it" "$HERE/../../scripts/apt-repo" "$WORK/repo" "$WORK/mavbond_${NEWER}_$(dpkg --print-architecture).deb"
    check "apt-get update" repo_update
    check "the candidate is $NEWER" candidate_is "$NEWER"
    check "apt-get upgrade takes it" "${APT[@]}" --only-upgrade install mavbond
    check "installed: $NEWER" version_installed "$NEWER"
    check "the edit survives the upgrade" edit_kept
    check "no .dpkg-new/.dpkg-dist left" no_dpkg_leftovers
    check "mavbond --check-config after the upgrade" /usr/bin/mavbond --check-config
    check "apt-get purge mavbond" "${APT[@]}" purge mavbond
    check "package and /etc/mavbond gone" purged
fi

tally install-test
