"""The internet-facing ports probed as an off-path attacker would (issue 22): strangers at
127.0.0.2 and 127.0.0.3, a local unprivileged user (uid 65534), against a ground gateway whose
LTE port listens on 0.0.0.0 in a bond, with and without `signing:`. Every probe counts its
successes from the daemon's own counters and from what the real peers (a vehicle, a GCS)
received, never from the clock: each asserts 0.

The vehicle and the GCS are pymavlink's encoders (an independent MAVLink stack), signing as
MAVLink 2 signing does where the endpoint has a key."""
from __future__ import annotations

import errno
import os
import re
import select
import signal
import socket
import subprocess
import threading
import time
from typing import Callable, List, Optional, Sequence

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from bonding_helpers import bond_config
from helpers import HOST, Daemon, corrupt_crc, free_port, raw_v2_frame, rss_kib, run_as

STRANGERS = ("127.0.0.2", "127.0.0.3")
NOBODY = 65534
VEHICLE = (1, 1)
GCS = (255, 190)
# A message id no dialect has: its CRC cannot be checked.
UNKNOWN_MSGID = 42424
# UdpServer::kSuccessionQuiet: how long an unsigned rebinding's old address must stay silent.
UDP_SUCCESSION_QUIET = 2.0


# --- peers ----------------------------------------------------------------------------------

def udp_at(host: str = HOST, port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    s.bind((host, port))
    return s


class Mav:
    """pymavlink's encoder for one (sysid, compid), each frame with the next sequence number;
    signed with `key` (MAVLink 2 signing) when given."""

    def __init__(self, sysid: int, compid: int, key: Optional[bytes] = None, link_id: int = 1):
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.link_id = link_id
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100000)
            self.mav.signing.sign_outgoing = True

    def pack(self, msg) -> bytes:
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data

    def heartbeat(self) -> bytes:
        return self.pack(self.mav.heartbeat_encode(6, 8, 0, 0, 4))

    def numbered(self, tag: str, n: int) -> bytes:
        return self.pack(self.mav.named_value_int_encode(0, tag.encode(), n))

    def command_long(self, target=VEHICLE, command: int = 400) -> bytes:  # 400: arm/disarm
        return self.pack(self.mav.command_long_encode(*target, command, 0, 1, 0, 0, 0, 0, 0, 0))

    def param_set(self, target=VEHICLE) -> bytes:
        return self.pack(self.mav.param_set_encode(*target, b"FENCE_ENABLE", 0.0, 9))


def parse(data: bytes) -> list:
    """The messages in `data`, by an unsigned parser (signatures are not its business)."""
    m = mavlink2.MAVLink(None)
    m.robust_parsing = True
    return [x for x in (m.parse_buffer(data) or []) if x.get_type() != "BAD_DATA"]


def numbers(msgs, tag: str) -> List[int]:
    return [x.value for x in msgs if x.get_type() == "NAMED_VALUE_INT" and x.name == tag]


def receive(sock: socket.socket, until: Callable[[list], bool], timeout: float = 15.0,
            quiet: Optional[float] = None) -> list:
    """Messages received on `sock` until until(messages) holds, or (with `quiet`) nothing came
    for that long, or the timeout passed."""
    got: list = []
    deadline = time.monotonic() + timeout
    last = time.monotonic()
    while time.monotonic() < deadline and not until(got):
        if quiet is not None and time.monotonic() - last > quiet:
            break
        r, _, _ = select.select([sock], [], [], 0.02)
        if r:
            got += parse(sock.recv(65536))
            last = time.monotonic()
    return got


def bytes_waiting(socks: Sequence[socket.socket], quiet: float = 0.5) -> int:
    """Every byte the sockets received (read until all were quiet for `quiet` seconds)."""
    total, last = 0, time.monotonic()
    while time.monotonic() - last < quiet:
        r, _, _ = select.select(list(socks), [], [], 0.05)
        for s in r:
            total += len(s.recv(65536))
            last = time.monotonic()
    return total


def noise(n: int) -> bytes:
    """Random bytes with no start byte in them: nothing a parser could take for a frame."""
    return bytes(b for b in os.urandom(2 * n) if b not in (0xFD, 0xFE))[:n]


def junk(maker: Mav) -> List[bytes]:
    """Datagrams no frame passes in: empty, noise, a bad CRC, an id whose CRC no one can check."""
    return [b"", noise(300), corrupt_crc(maker.heartbeat()),
            raw_v2_frame(UNKNOWN_MSGID, b"\x01\x02\x03\x04", sysid=1, compid=1)]


# --- the ground gateway ---------------------------------------------------------------------

class Counters(dict):
    """An endpoint's counters; one this daemon does not have reads -1 (a build without it
    fails the probe's wait or assertion, not with a KeyError)."""

    def __missing__(self, key):
        return -1


class Ground:
    """A ground gateway: `lte`, a UDP server on 0.0.0.0 in bond `vehicle` (signed with a fresh
    key when `signed`), and `gcs`, a UDP server on 127.0.0.1."""

    def __init__(self, mavbond_bin: str, tmp_path, signed: bool, name: str = "ground",
                 **lte_options):
        self.key = os.urandom(32) if signed else None
        self.lte_port, self.gcs_port = free_port(), free_port()
        lte = {"name": "lte", "type": "udp", "mode": "server",
               "address": f"0.0.0.0:{self.lte_port}", "bond": "vehicle", **lte_options}
        bond = {"name": "vehicle"}
        if self.key is not None:  # the bond signs its link, as the shipped examples do
            key_file = tmp_path / f"{name}.key"
            key_file.write_text(self.key.hex() + "\n")
            key_file.chmod(0o600)
            bond["signing"] = f"{{key_file: {key_file}}}"
        config = bond_config([lte, {"name": "gcs", "type": "udp", "mode": "server",
                                    "address": f"{HOST}:{self.gcs_port}"}],
                             bonds=[bond], report_interval="1s")
        self.daemon = Daemon(mavbond_bin, tmp_path, config, name=name)
        self.daemon.endpoint_names = ["lte", "gcs"]  # not the bond's name
        self.daemon.start()
        self.lte = (HOST, self.lte_port)
        self.gcs = (HOST, self.gcs_port)

    def vehicle(self) -> Mav:
        return Mav(*VEHICLE, key=self.key)

    def new_peer(self, sock: socket.socket, count: int = 1) -> str:
        host, port = sock.getsockname()
        return self.daemon.wait_log(rf"\[udp:lte\] new peer {host}:{port}\b", count=count)

    def lte_when(self, done: Callable[[dict], bool]) -> dict:
        """The LTE port's counters once done(counters) holds: the daemon took what was sent
        (under a flood the log says only so much of who came and went)."""
        return Counters(self.daemon.wait_stats(lambda s: done(Counters(s["lte"])))["lte"])

    def stop(self):
        self.daemon.kill()


@pytest.fixture
def ground(mavbond_bin, tmp_path):
    made: List[Ground] = []

    def make(signed: bool, **kw) -> Ground:
        g = Ground(mavbond_bin, tmp_path, signed, name=f"ground{len(made)}", **kw)
        made.append(g)
        return g

    yield make
    for g in made:
        g.stop()


@pytest.fixture
def socks():
    made: List[socket.socket] = []

    def make(host: str = HOST, port: int = 0, kind=socket.SOCK_DGRAM) -> socket.socket:
        s = udp_at(host, port) if kind == socket.SOCK_DGRAM else socket.socket(socket.AF_INET, kind)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def gcs_commands(g: Ground, gcs_sock: socket.socket) -> List[str]:
    """The GCS says hello, then commands the vehicle: what a stranger must never receive."""
    gcs = Mav(*GCS)
    frames = [gcs.heartbeat(), gcs.command_long(), gcs.param_set(), gcs.heartbeat()]
    for f in frames:
        gcs_sock.sendto(f, g.gcs)
    return [m.get_type() for m in parse(b"".join(frames))]


# --- 1. a datagram is not a peer ------------------------------------------------------------

@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_a_strangers_datagrams_join_nothing_and_receive_nothing(ground, socks, signed):
    """Strangers send empty datagrams, noise, bad CRCs, frames no CRC can check (and, where
    the port is signed, the vehicle's frames unsigned, signed with another key, and a replay
    of the vehicle's own): none becomes a peer. The GCS's COMMAND_LONG, PARAM_SET and
    HEARTBEATs reach the vehicle and no stranger; each stranger datagram is counted."""
    g = ground(signed)
    vehicle_sock, gcs_sock = socks(), socks()
    strangers = [socks(host) for host in STRANGERS for _ in range(3)]
    vehicle = g.vehicle()
    forgers = [Mav(*VEHICLE), Mav(*VEHICLE, key=os.urandom(32))]  # unsigned, another key
    sent = {"datagrams": 0, "unsigned": 0, "bad": 0, "replay": 0}

    def probe(replay: Optional[bytes] = None):
        for s in strangers:
            batch = junk(forgers[0])
            if signed:
                batch += [forgers[0].command_long(), forgers[1].command_long()]
                sent["unsigned"] += 2  # the forger's, and junk's frame of an unknown id
                sent["bad"] += 1
            for d in batch:
                s.sendto(d, g.lte)
            sent["datagrams"] += len(batch)
        if replay is not None:
            strangers[0].sendto(replay, g.lte)
            sent["datagrams"] += 1
            sent["replay"] += 1

    probe()  # before the vehicle is known
    captured = vehicle.heartbeat()
    vehicle_sock.sendto(captured, g.lte)
    g.new_peer(vehicle_sock)
    probe(replay=captured if signed else None)  # and after
    st = g.lte_when(lambda s: s["stranger_datagrams"] >= sent["datagrams"])
    want = gcs_commands(g, gcs_sock)
    got = receive(vehicle_sock, lambda m: len(m) >= len(want))
    stolen = bytes_waiting(strangers)
    log = g.daemon.log()
    print(f"\n{'signed' if signed else 'unsigned'}: {sent['datagrams']} stranger datagrams, "
          f"counted {st['stranger_datagrams']}; sig_unsigned {st['sig_unsigned']}, sig_bad "
          f"{st['sig_bad']}, sig_replay {st['sig_replay']}; vehicle got {[m.get_type() for m in got]}; "
          f"strangers got {stolen} bytes")
    assert [m.get_type() for m in got] == want, "the vehicle gets every GCS frame"
    assert stolen == 0, "no stranger receives anything"
    assert st["stranger_datagrams"] == sent["datagrams"]
    assert (st["sig_unsigned"], st["sig_bad"], st["sig_replay"]) == (
        sent["unsigned"], sent["bad"], sent["replay"])
    assert log.count("[udp:lte] new peer") == 1
    assert all(f"new peer {h}" not in log for h in STRANGERS)


# --- 2. a full table never locks the vehicle out --------------------------------------------

@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_a_full_table_of_strangers_never_locks_the_vehicle_out(ground, socks, signed):
    """63 stranger ports each send a valid-looking unsigned frame (filling the 64-peer table
    beside the vehicle, where nothing is signed), then 64 fresh ports do; then the vehicle's
    NAT moves its port. The vehicle gets every GCS frame sent after its first datagram from
    the new port; with signing no stranger ever took a place or received a byte."""
    g = ground(signed)
    old, gcs_sock = socks(), socks()
    vehicle = g.vehicle()
    old.sendto(vehicle.heartbeat(), g.lte)
    g.new_peer(old)
    flood = [socks(STRANGERS[i % 2]) for i in range(63 + 64)]
    for i, s in enumerate(flood):
        s.sendto(Mav(100 + i % 100, 1).heartbeat(), g.lte)
    # Every frame sent so far parsed (the strangers' too: signing refuses them after).
    g.lte_when(lambda s: s["rx_frames"] >= 1 + len(flood))
    old.close()
    new = socks()  # the NAT's new mapping
    new.sendto(vehicle.heartbeat(), g.lte)
    g.lte_when(lambda s: s["rx_frames"] >= 2 + len(flood))
    gcs = Mav(*GCS)
    for n in range(20):
        gcs_sock.sendto(gcs.numbered("cmd", n), g.gcs)
    got = numbers(receive(new, lambda m: len(numbers(m, "cmd")) >= 20), "cmd")
    stolen = bytes_waiting(flood)
    st = g.lte_when(lambda s: True)
    print(f"\n{'signed' if signed else 'unsigned'}: vehicle after its NAT moved got {len(got)} of 20; "
          f"peers_evicted {st['peers_evicted']}, stranger_datagrams {st['stranger_datagrams']}, "
          f"peer_rebinds {st['peer_rebinds']}; the {len(flood)} stranger ports got {stolen} bytes")
    assert got == list(range(20))
    if signed:
        assert stolen == 0 and st["stranger_datagrams"] == len(flood)
        assert st["peers_evicted"] == 0 and st["peer_rebinds"] == 1
    else:
        # Unsigned, a valid frame is a peer's: the strangers took places, the least recently
        # heard made room each time (the vehicle's old address first), none was refused.
        assert st["stranger_datagrams"] == 0
        assert st["peers_evicted"] == len(flood) + 2 - 64
    assert "already: ignoring new peer" not in g.daemon.log()


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
def test_a_silent_vehicle_returning_during_a_flood_is_admitted(ground, socks, signed):
    """64 stranger ports flood the LTE port with valid-looking unsigned frames while the
    vehicle is silent longer than peer_timeout; it comes back from a new port during the
    flood and gets every GCS command from then on. The flood and the vehicle go in one
    order into one socket (so the daemon's view does not depend on the scheduler): unsigned,
    the vehicle sends more often than each stranger port (a stranger port faster than the
    vehicle can crowd it out of a table of 64 without signing; with signing none is let in)."""
    g = ground(signed, peer_timeout="2s")
    old, gcs_sock = socks(), socks()
    vehicle = g.vehicle()
    old.sendto(vehicle.heartbeat(), g.lte)
    g.new_peer(old)
    flood = [socks(STRANGERS[i % 2]) for i in range(64)]
    makers = [Mav(100 + i, 1) for i in range(64)]
    sent = 0

    def flood_round(k: int, share: int = 16):
        nonlocal sent
        for i in range(k * share, (k + 1) * share):
            flood[i % 64].sendto(makers[i % 64].heartbeat(), g.lte)
            sent += 1

    # Until the vehicle's old address is gone: forgotten after peer_timeout (signed: the
    # strangers never take a place), or crowded out by the strangers (unsigned).
    gone = rf"\[udp:lte\] peer 127\.0\.0\.1:{old.getsockname()[1]} silent for"
    k = 0
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        flood_round(k)
        k += 1
        time.sleep(0.05)
        if re.search(gone, g.daemon.log()) if signed else g.lte_when(lambda s: True)["peers_evicted"] > 0:
            break
    old.close()
    new = socks()
    new.sendto(vehicle.heartbeat(), g.lte)
    # Every frame sent so far parsed (the strangers' too: signing refuses them after).
    g.lte_when(lambda s: s["rx_frames"] >= sent + 2)
    gcs = Mav(*GCS)
    got: List[int] = []
    for n in range(100):
        flood_round(k)
        k += 1
        new.sendto(vehicle.heartbeat(), g.lte)
        gcs_sock.sendto(gcs.numbered("cmd", n), g.gcs)
        got += numbers(receive(new, lambda m: len(numbers(m, "cmd")) >= 1, timeout=2), "cmd")
    got += numbers(receive(new, lambda m: False, quiet=0.3), "cmd")
    st = g.lte_when(lambda s: s["rx_frames"] >= sent + 2 + 100)
    stolen = bytes_waiting(flood) if signed else None
    print(f"\n{'signed' if signed else 'unsigned'}: {sent} flood datagrams from 64 ports; the "
          f"returning vehicle got {len(got)} of 100 commands; peers_evicted {st['peers_evicted']}, "
          f"stranger_datagrams {st['stranger_datagrams']}; strangers got "
          f"{stolen if signed else 'copies (unsigned, they are peers)'}")
    assert got == list(range(100)), "every command after its return, once, in order"
    if signed:
        assert stolen == 0 and st["stranger_datagrams"] == sent and st["peers_evicted"] == 0
    else:
        assert st["stranger_datagrams"] == 0 and st["peers_evicted"] >= 1


# --- 3. hijack by guessing the sequence (unsigned) -------------------------------------------

def test_guessing_the_vehicles_next_sequence_number_takes_nothing_over(ground, socks):
    """Without signing, 12 strangers (12 trials) each carry the vehicle's stream on from an
    address of their own, their first frame exactly the vehicle's next sequence number, 12
    datagrams each over 2.4 s, while the vehicle keeps sending from its address: 0 takeovers,
    and the vehicle gets every GCS frame. Then the vehicle's NAT really moves (the old address
    silent, the new one carrying the stream on): followed, so the rule is alive."""
    g = ground(False)
    vehicle_sock, gcs_sock = socks(), socks()
    vehicle, gcs = g.vehicle(), Mav(*GCS)
    strangers = [socks(STRANGERS[i % 2]) for i in range(12)]
    guessers = [Mav(*VEHICLE) for _ in strangers]
    vehicle_sock.sendto(vehicle.numbered("ap", 0), g.lte)
    g.new_peer(vehicle_sock)
    got: List[int] = []
    for step in range(12):
        vehicle_sock.sendto(vehicle.numbered("ap", step + 1), g.lte)
        for s, guess in zip(strangers, guessers):
            guess.mav.seq = vehicle.mav.seq  # the vehicle's next sequence number, exactly
            s.sendto(guess.numbered("ap", 1000 + step), g.lte)
        gcs_sock.sendto(gcs.numbered("cmd", step), g.gcs)
        got += numbers(receive(vehicle_sock, lambda m: len(numbers(m, "cmd")) >= 1), "cmd")
        time.sleep(0.2)
    st = g.lte_when(lambda s: s["rx_frames"] >= 1 + 12 + 12 * 12)
    takeovers = st["peer_rebinds"]
    print(f"\n12 guessers x 12 datagrams: {takeovers} takeovers; the vehicle got {len(got)} of 12 "
          f"GCS frames")
    assert takeovers == 0
    assert got == list(range(12))
    # The control: the vehicle's NAT moves, the old address goes silent.
    moved = socks()
    for n in range(4):
        moved.sendto(vehicle.numbered("ap", 100 + n), g.lte)
        time.sleep(UDP_SUCCESSION_QUIET / 3 + 0.05)
    text = g.daemon.wait_log(rf"peer 127\.0\.0\.1:{vehicle_sock.getsockname()[1]} now at "
                             rf"127\.0\.0\.1:{moved.getsockname()[1]} \(a NAT rebinding\)")
    print(f"then its real move: {text.count('(a NAT rebinding)')} rebinding")
    assert text.count("(a NAT rebinding)") == 1


# --- 4. the port belongs to the daemon --------------------------------------------------------

class Thief:
    """uid 65534 binding `addr` with SO_REUSEADDR and SO_REUSEPORT in a child process, told
    that it may stop through a pipe. report(): 'error:ERRNO' if the kernel refused the bind,
    else 'bound:N', N the datagrams (or connections) it took."""

    def __init__(self, kind: int, addr):
        ready_r, ready_w = os.pipe()
        self._stop_r, self._stop_w = os.pipe()
        stop_r = self._stop_r

        def work() -> str:
            s = socket.socket(socket.AF_INET, kind)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            try:
                s.bind(addr)
                if kind == socket.SOCK_STREAM:
                    s.listen(16)
            except OSError as e:
                return f"error:{e.errno}"
            finally:
                os.write(ready_w, b"x")
            got = 0
            while True:
                r, _, _ = select.select([s, stop_r], [], [], 1.0)
                if stop_r in r:
                    return f"bound:{got}"
                if s in r:
                    if kind == socket.SOCK_DGRAM:
                        s.recv(65536)
                    else:
                        s.accept()[0].close()
                    got += 1

        self._result = run_as(NOBODY, NOBODY, work, timeout=30)
        os.close(ready_w)
        os.read(ready_r, 1)  # bound, or refused
        os.close(ready_r)

    def report(self) -> str:
        os.write(self._stop_w, b"x")
        out = self._result()
        os.close(self._stop_w)
        os.close(self._stop_r)
        return out


needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to play uid 65534")


@needs_root
@pytest.mark.parametrize("host", ["0.0.0.0", HOST])
def test_a_local_user_cannot_take_the_daemons_ports(mavbond_bin, tmp_path, socks, host):
    """The daemon listens first (UDP and TCP, on `host`); uid 65534 binds the same port with
    SO_REUSEADDR and SO_REUSEPORT, on the same address and on 127.0.0.1: refused each time,
    and the daemon gets all 100 datagrams a sender sends meanwhile."""
    udp_port, tcp_port = free_port(), free_port(socket.SOCK_STREAM)
    d = Daemon(mavbond_bin, tmp_path, bond_config([
        {"name": "gcs", "type": "udp", "mode": "server", "address": f"{host}:{udp_port}"},
        {"name": "api", "type": "tcp", "mode": "server", "address": f"{host}:{tcp_port}"}]),
        ).start()
    sender, m = socks(), Mav(*GCS)
    results, sent = {}, 0
    try:
        for kind, port in ((socket.SOCK_DGRAM, udp_port), (socket.SOCK_STREAM, tcp_port)):
            for addr in sorted({host, HOST}):
                thief = Thief(kind, (addr, port))
                if kind == socket.SOCK_DGRAM:
                    for _ in range(100):
                        sender.sendto(m.numbered("n", sent), (HOST, port))
                        sent += 1
                results[f"{'udp' if kind == socket.SOCK_DGRAM else 'tcp'} {addr}"] = thief.report()
        st = d.wait_stats(lambda s: s["gcs"]["rx_frames"] >= sent)
    finally:
        d.kill()
    print(f"\ndaemon on {host}: the thief's binds {results}; the daemon got "
          f"{st['gcs']['rx_frames']} of {sent} datagrams")
    assert all(v == f"error:{errno.EADDRINUSE}" for v in results.values()), "refused every time"
    assert st["gcs"]["rx_frames"] == sent


@needs_root
@pytest.mark.parametrize("host", ["0.0.0.0", HOST])
def test_a_port_a_local_user_holds_is_a_clear_error_at_start_and_at_reload(
        mavbond_bin, tmp_path, host):
    """uid 65534 binds a UDP port first (SO_REUSEADDR, SO_REUSEPORT): the daemon that should
    listen there does not start (exit 71, the address and 'Address already in use' named), so
    nothing is silently shared; at a reload, the endpoint is reported and left out, the rest
    runs on."""
    port, other = free_port(), free_port()
    thief = Thief(socket.SOCK_DGRAM, (HOST, port))
    try:
        cfg = tmp_path / "taken.yaml"
        cfg.write_text(bond_config([{"name": "gcs", "type": "udp", "mode": "server",
                                     "address": f"{host}:{port}"}]))
        r = subprocess.run([mavbond_bin, "-c", str(cfg)], capture_output=True, text=True,
                           timeout=10)
        keep = {"name": "keep", "type": "udp", "mode": "server", "address": f"{HOST}:{other}"}
        running = Daemon(mavbond_bin, tmp_path, bond_config([keep]), name="reloaded").start()
        try:
            running.config_path.write_text(bond_config([keep, {
                "name": "gcs", "type": "udp", "mode": "server", "address": f"{host}:{port}"}]))
            running.proc.send_signal(signal.SIGHUP)
            log = running.wait_log(r"reloaded: .* 1 failed")
            alive = running.alive()
        finally:
            running.kill()
    finally:
        stolen = thief.report()
    line = next(l for l in log.splitlines() if "reload: endpoint 'gcs'" in l)
    print(f"\nthief {stolen}; start: exit {r.returncode}: {r.stderr.strip().splitlines()[-1]}\n"
          f"reload: {line.strip()}")
    assert stolen.startswith("bound:")
    assert r.returncode == 71
    assert f"cannot bind {host}:{port}: Address already in use" in r.stderr
    assert f"ss -ulpn 'sport = :{port}'" in r.stderr
    assert f"cannot bind {host}:{port}: Address already in use" in line
    assert alive


# --- 5. tables a stranger can fill ------------------------------------------------------------

def cpu_seconds(pid: int) -> float:
    """The process's time on a CPU so far, to the nanosecond (schedstat, every thread)."""
    tasks = f"/proc/{pid}/task"
    return sum(int(open(f"{tasks}/{t}/schedstat").read().split()[0])
               for t in os.listdir(tasks)) / 1e9


def test_a_stranger_cycling_ids_fills_one_links_routes_and_no_more(mavbond_bin, tmp_path, socks):
    """A stranger on the GCS port (unsigned, on 0.0.0.0 as the shipped ground example has it)
    sends one frame from every (sysid, compid) there is: its link keeps 128 routes, the least
    recently heard forgotten first, counted (routes_evicted = 65,536 - 128), and a command to
    the vehicle after it reaches the vehicle only. The daemon's RSS and CPU for the same
    legitimate load, before and after the flood, are printed (figures, not assertions)."""
    gcs_port, veh_port = free_port(), free_port()
    d = Daemon(mavbond_bin, tmp_path, bond_config([
        {"name": "gcs", "type": "udp", "mode": "server", "address": f"0.0.0.0:{gcs_port}"},
        {"name": "fc", "type": "udp", "mode": "server", "address": f"{HOST}:{veh_port}"}],
        route_timeout="300s")).start()
    vehicle_sock, gcs_sock, stranger = socks(), socks(), socks(STRANGERS[0])
    vehicle, gcs = Mav(*VEHICLE), Mav(*GCS)
    vehicle_sock.sendto(vehicle.heartbeat(), (HOST, veh_port))
    d.wait_log(r"\[udp:fc\] new peer")
    gcs_sock.sendto(gcs.heartbeat(), (HOST, gcs_port))
    d.wait_log(r"\[udp:gcs\] new peer")

    def legit_load(rounds: int = 400) -> float:
        """Telemetry up, commands down, in lockstep; the daemon's CPU seconds for it."""
        before = cpu_seconds(d.proc.pid)
        for n in range(rounds):
            vehicle_sock.sendto(vehicle.numbered("t", n), (HOST, veh_port))
            gcs_sock.sendto(gcs.command_long(), (HOST, gcs_port))
            receive(gcs_sock, lambda m: len(numbers(m, "t")) >= 1)
            receive(vehicle_sock, lambda m: any(x.get_type() == "COMMAND_LONG" for x in m))
        return cpu_seconds(d.proc.pid) - before

    cpu_before, rss_before = legit_load(), rss_kib(d.proc.pid)
    ids = [(s, c) for s in range(256) for c in range(256)]
    for i in range(0, len(ids), 32):
        stranger.sendto(b"".join(Mav(s, c).heartbeat() for s, c in ids[i:i + 32]),
                        (HOST, gcs_port))
    d.wait_stats(lambda s: s["gcs"]["rx_frames"] >= 1 + 400 + len(ids), timeout=60)
    rss_after = rss_kib(d.proc.pid)
    bytes_waiting([vehicle_sock], quiet=0.3)  # the stranger's frames, broadcast
    cpu_after = legit_load()
    bytes_waiting([stranger, vehicle_sock], quiet=0.2)
    gcs_sock.sendto(gcs.command_long(), (HOST, gcs_port))
    got = receive(vehicle_sock, lambda m: any(x.get_type() == "COMMAND_LONG" for x in m))
    to_stranger = bytes_waiting([stranger])
    st = d.wait_stats(lambda s: s["gcs"]["rx_frames"] >= 1 + 800 + len(ids) + 1)
    print(f"\n65,536 ids from one stranger: routes_evicted {st['gcs']['routes_evicted']}; RSS "
          f"{rss_before} -> {rss_after} KiB; daemon CPU for the same 400 legitimate exchanges "
          f"{cpu_before * 1e3:.1f} ms before, {cpu_after * 1e3:.1f} ms after (the stranger, a peer of "
          f"the unsigned port now, gets the telemetry too); a command after it reached the "
          f"vehicle: {[m.get_type() for m in got]}, the stranger {to_stranger} bytes")
    d.kill()
    assert st["gcs"]["rx_frames"] >= len(ids)
    assert st["gcs"]["routes_evicted"] == len(ids) - 128
    assert st["fc"]["routes_evicted"] == 0
    assert [m.get_type() for m in got] == ["COMMAND_LONG"]
    assert to_stranger == 0, "the vehicle's route stays the vehicle's"


def tcp_connect(host: str, port: int, source: str) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind((source, 0))
    s.settimeout(5)
    s.connect((host, port))
    return s


def closed_by_peer(s: socket.socket, timeout: float) -> bool:
    s.settimeout(timeout)
    try:
        while True:
            data = s.recv(65536)
            if not data:
                return True
    except (socket.timeout, BlockingIOError):
        return False
    except ConnectionResetError:
        return True


def test_tcp_strangers_hold_no_place(mavbond_bin, tmp_path, socks):
    """40 connections from two stranger addresses: 8 from each are accepted (the default
    max_clients_per_address), the other 24 refused and counted, and a ground station from
    127.0.0.1 connects during the flood and gets the vehicle's frames. On a server with
    idle_timeout 2s, idle strangers' connections are closed while a ground station sending
    its HEARTBEAT keeps its place. Strangers reconnecting for 3 s make hundreds of refusals:
    the log says so in a line per report_interval with the count, never a line each."""
    tcp_port, idle_port, src_port = (free_port(socket.SOCK_STREAM) for _ in range(3))
    d = Daemon(mavbond_bin, tmp_path, bond_config([
        {"name": "tcp", "type": "tcp", "mode": "server", "address": f"0.0.0.0:{tcp_port}",
         "idle_timeout": "60s"},
        {"name": "idle", "type": "tcp", "mode": "server", "address": f"0.0.0.0:{idle_port}",
         "idle_timeout": "2s"},
        {"name": "src", "type": "udp", "mode": "server", "address": f"{HOST}:{src_port}"}],
        report_interval="1s")).start()
    src, vehicle, g = socks(), Mav(*VEHICLE), Mav(*GCS)
    opened: List[socket.socket] = []

    def connect(port: int, source: str) -> socket.socket:
        opened.append(tcp_connect(HOST, port, source))
        return opened[-1]

    def talk(gcs: socket.socket, server: str, n: int) -> List[int]:
        """The GCS says HEARTBEAT until the daemon counts it (so it is attached), then the
        vehicle sends n numbered frames: what the GCS got of them."""
        before = d.stats()[server]["rx_frames"]
        gcs.sendall(g.heartbeat())
        d.wait_stats(lambda s: s[server]["rx_frames"] > before)
        for k in range(n):
            src.sendto(vehicle.numbered("t", k), (HOST, src_port))
        return numbers(receive(gcs, lambda m: len(numbers(m, "t")) >= n), "t")

    try:
        flood = [connect(tcp_port, STRANGERS[i % 2]) for i in range(40)]
        # Accepted in order: once 24 are refused, all 40 were taken (the first 16 accepted).
        refused = d.wait_stats(lambda s: s["tcp"]["clients_refused"] >= 24)["tcp"]["clients_refused"]
        ended = sum(closed_by_peer(s, 0.3) for s in flood)
        gcs = connect(tcp_port, HOST)
        got_during_flood = talk(gcs, "tcp", 50)

        idle_strangers = [connect(idle_port, STRANGERS[i % 2]) for i in range(8)]
        keeper = connect(idle_port, HOST)
        start = time.monotonic()
        while time.monotonic() - start < 4.5:  # past idle_timeout; the GCS's HEARTBEATs go on
            keeper.sendall(g.heartbeat())
            time.sleep(0.05)
        idle = d.wait_stats(lambda s: s["idle"]["clients_idle_closed"] >= 8)["idle"]
        idle_ended = sum(closed_by_peer(s, 0.3) for s in idle_strangers)
        got_after_idle = talk(keeper, "idle", 10)

        end = time.monotonic() + 3
        attempts = 0
        while time.monotonic() < end:
            for host in STRANGERS:
                try:
                    tcp_connect(HOST, tcp_port, host).close()
                except OSError:
                    pass
                attempts += 1
        # Accepted in order: once a last client's frame is counted, every refusal is.
        talk(connect(tcp_port, HOST), "tcp", 1)
        total = d.stats()["tcp"]["clients_refused"]
        said = lambda: [int(m.group(1)) for m in re.finditer(  # noqa: E731
            r"\[tcp\] (\d+) connections refused \(max_clients_per_address or 32 clients\)",
            d.log())]
        deadline = time.monotonic() + 5
        while sum(said()) < total and time.monotonic() < deadline:
            time.sleep(0.1)
        lines = said()
        log = d.log()
    finally:
        for s in opened:
            s.close()
        d.kill()
    print(f"\n40 stranger connections: {40 - refused} accepted, {refused} refused ({ended} ended "
          f"at once); the GCS connecting during the flood got {len(got_during_flood)} of 50 "
          f"frames. idle_timeout 2s: {idle['clients_idle_closed']} idle strangers closed "
          f"({idle_ended} of 8 saw the end), the talking GCS got {len(got_after_idle)} of 10 "
          f"after. {attempts} reconnects: clients_refused {total}, said in {len(lines)} log "
          f"lines {lines}")
    assert refused == 40 - 2 * 8 and ended == refused, "8 per address, the rest refused at once"
    assert got_during_flood == list(range(50))
    assert idle["clients_idle_closed"] == 8 and idle_ended == 8
    assert got_after_idle == list(range(10)), "the GCS that talks keeps its place"
    assert sum(lines) == total, "every refusal counted in the log's lines"
    assert len(lines) <= total / 10, "a line per report_interval with a count, not one each"
    assert "refusing" not in log


# --- 6. a flood with signing on loses no legitimate frame -------------------------------------

def test_a_flood_of_everything_loses_no_signed_frame(ground, socks):
    """While 64 stranger ports send every kind of datagram (empty, noise, bad CRCs, unchecked
    ids, the vehicle's frames unsigned, signed with another key, and replays of its own), the
    signed vehicle sends 3,000 numbered frames and the GCS 300 commands: every one arrives
    once, in order; every stranger datagram is counted, none got a byte. The flood is bounded
    to what the receive buffer holds (no kernel drop, whatever the scheduler does: asserted)."""
    g = ground(True)
    vehicle_sock, gcs_sock = socks(), socks()
    vehicle, gcs = g.vehicle(), Mav(*GCS)
    vehicle_sock.sendto(vehicle.heartbeat(), g.lte)
    g.new_peer(vehicle_sock)
    gcs_sock.sendto(gcs.heartbeat(), g.gcs)
    g.daemon.wait_log(r"\[udp:gcs\] new peer")
    strangers = [socks(STRANGERS[i % 2]) for i in range(64)]
    forgers = [Mav(*VEHICLE), Mav(*VEHICLE, key=os.urandom(32))]
    captured: List[bytes] = []
    counts = {"datagrams": 0, "unsigned": 0, "bad": 0, "replay": 0}
    stop = threading.Event()

    def flood():
        for rnd in range(20):
            for s in strangers:
                batch = junk(forgers[0]) + [forgers[0].command_long(), forgers[1].command_long()]
                counts["unsigned"] += 2  # the forger's, and junk's frame of an unknown id
                counts["bad"] += 1
                if captured:
                    batch.append(captured[rnd % len(captured)])
                    counts["replay"] += 1
                for d in batch:
                    s.sendto(d, g.lte)
                counts["datagrams"] += len(batch)
            if stop.is_set():
                return

    flooder = threading.Thread(target=flood)
    up: List[int] = []
    down: List[int] = []
    flooder.start()
    try:
        for n in range(3000):
            frame = vehicle.numbered("ap", n)
            vehicle_sock.sendto(frame, g.lte)
            if n < 50:  # captured once sent: a replay comes after it into the same socket
                captured.append(frame)
            if n % 10 == 0:
                gcs_sock.sendto(gcs.numbered("cmd", n // 10), g.gcs)
            if n % 100 == 99:
                up += numbers(receive(gcs_sock, lambda m: len(up) + len(numbers(m, "ap")) >= n + 1), "ap")
                down += numbers(receive(vehicle_sock, lambda m: len(down) + len(numbers(m, "cmd")) >= n // 10 + 1), "cmd")
    finally:
        stop.set()
        flooder.join(30)
    total = counts["datagrams"]
    st = g.lte_when(lambda s: s["stranger_datagrams"] >= total)
    stolen = bytes_waiting(strangers)
    print(f"\nsigned, under a flood of {total} stranger datagrams: GCS got {len(up)} of 3000, "
          f"vehicle {len(down)} of 300; counted stranger_datagrams {st['stranger_datagrams']}, "
          f"sig_unsigned {st['sig_unsigned']}, sig_bad {st['sig_bad']}, sig_replay "
          f"{st['sig_replay']}, rx_overflows {st['rx_overflows']}; strangers got {stolen} bytes")
    assert up == list(range(3000)) and down == list(range(300))
    assert st["rx_overflows"] == 0
    assert st["stranger_datagrams"] == total
    assert (st["sig_unsigned"], st["sig_bad"], st["sig_replay"]) == (
        counts["unsigned"], counts["bad"], counts["replay"])
    assert stolen == 0
