"""The setup of tests/peers: an independent vehicle (MAVSDK's server components) on a UART
(a pseudo-terminal pair joined to mavbond's by a null-modem wire), an air-side mavbond, two
emulated links (tests/peers/cutlinks.py: linkemu with cuts that follow the traffic), a
ground-side mavbond, and a ground station (MAVSDK's clients, or MAVProxy) on TCP. Each
gateway writes a flight log (a tlog endpoint): the air one holds exactly what the vehicle
sent and what was delivered to it, the ground one what the ground station sent and what was
delivered to it. Those two logs and the emulator's records (every datagram each link received,
the gateways' count markers among them, and which it dropped) are the evidence the tests
judge by; nothing is judged by how long anything took."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path
from typing import Dict, List, Optional

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "integration"))

from helpers import HOST, free_port, tcp_server, udp_client, udp_server  # noqa: E402
from bonding_helpers import EmuGroup, Gateway  # noqa: E402

VEHICLE = (1, 1)           # MAVSDK's autopilot: system 1, component 1
GCS = (245, 190)           # MAVSDK's ground station
BAUD = 921600
# The links: each loses 5 % (seeded: the same datagrams every run), one 300 ms behind the
# other, both directions.
FAST = {"loss": "5%", "delay": "10ms"}
SLOW = {"loss": "5%", "delay": "310ms"}
CLEAN = {"delay": "10ms"}
SEEDS = {"fast": 1301, "slow": 1302, "clean": 1303}
# MAVSDK's retry timeout on both ends: above the slow link's round trip (620 ms) with room,
# so a retry means a lost frame, never a slow one (MAVSDK's mission server stores an item it
# gets twice twice: a retry for a late answer would corrupt the mission).
MAVSDK_TIMEOUT = 1.5
ATTITUDE = 30              # the vehicle publishes it at 20 Hz (mavsdk_vehicle.RATES)


class PtyWire:
    """Two pseudo-terminals joined master to master by a thread, as a null-modem cable joins
    two UARTs: whatever one side's slave is written, the other side's slave reads. Each side
    gets its slave's path (/dev/pts/N). The slaves stay open here too, so bytes written
    before a side opens its device wait in the pty instead of failing."""

    def __init__(self):
        self.sides = []
        for _ in range(2):
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            os.set_blocking(master, False)
            self.sides.append((master, slave, os.ttyname(slave)))
        self.paths = [s[2] for s in self.sides]
        self.bytes = [0, 0]          # bytes carried from side 0 to 1, from 1 to 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, name="ptywire", daemon=True)
        self._t.start()

    def _run(self) -> None:
        (ma, _, _), (mb, _, _) = self.sides
        pending = {ma: bytearray(), mb: bytearray()}   # bytes waiting to be written to it
        other = {ma: mb, mb: ma}
        while not self._stop.is_set():
            wlist = [fd for fd, buf in pending.items() if buf]
            r, w, _ = select.select([ma, mb], wlist, [], 0.1)
            for fd in r:
                try:
                    data = os.read(fd, 65536)
                except (BlockingIOError, OSError):
                    continue
                pending[other[fd]] += data
                self.bytes[0 if fd == ma else 1] += len(data)
            for fd in w:
                try:
                    n = os.write(fd, pending[fd])
                    del pending[fd][:n]
                except (BlockingIOError, OSError):
                    pass

    def close(self) -> None:
        self._stop.set()
        self._t.join(2)
        for master, slave, _ in self.sides:
            for fd in (master, slave):
                try:
                    os.close(fd)
                except OSError:
                    pass


class Process:
    """A helper process whose stdout is JSON lines, stderr to a file."""

    def __init__(self, workdir: Path, name: str, argv: List[str], env: Optional[dict] = None):
        self.name = name
        self.out_path = workdir / f"{name}.out"
        self.err_path = workdir / f"{name}.err"
        self._out = open(self.out_path, "wb")
        self._err = open(self.err_path, "wb")
        # MAVSDK leaves its component-metadata cache in the temp directory: the run's own.
        env = dict(os.environ if env is None else env, TMPDIR=str(workdir))
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=self._out,
                                     stderr=self._err, env=env)

    def lines(self) -> List[dict]:
        text = self.out_path.read_text(errors="replace")
        out = []
        for line in text[:text.rfind("\n") + 1].splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                pass
        return out

    def wait_line(self, key: str, value, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            for d in self.lines():
                if d.get(key) == value:
                    return d
            if self.proc.poll() is not None:
                raise AssertionError(f"{self.name} exited with {self.proc.returncode} before "
                                     f"{key}={value}: {self.tail()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{self.name}: no {key}={value} within {timeout} s: "
                                     f"{self.tail()}")
            time.sleep(0.05)

    def tail(self, n: int = 3000) -> str:
        err = self.err_path.read_text(errors="replace")
        err = "\n".join(l for l in err.splitlines() if "not extended" not in l)
        return f"stdout: {self.out_path.read_text(errors='replace')[-n:]}\nstderr: {err[-n:]}"

    def wait(self, timeout: float) -> Optional[int]:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, timeout: float = 10.0) -> Optional[int]:
        """SIGTERM, then SIGKILL after `timeout`; the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._out.close()
        self._err.close()
        return self.proc.returncode


def ftp_blob(path: Path, size: int = 256 * 1024, seed: int = 13) -> Path:
    """The file served by FTP: `size` bytes from a seeded generator (every run the same)."""
    import random
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(random.Random(seed).randbytes(size))
    return path


class PeerLab:
    """Gateways and emulators for one scenario in its own directory; kill() ends whatever is
    still running (the tests' teardown calls it whatever happened)."""

    def __init__(self, binary: str, plugin_dir: str, workdir: Path):
        self.binary, self.plugin_dir, self.workdir = binary, plugin_dir, workdir
        workdir.mkdir(parents=True, exist_ok=True)
        self.gateways: List[Gateway] = []
        self.emus: List[EmuGroup] = []
        self.procs: List[Process] = []
        self.wires: List[PtyWire] = []

    def gateway(self, endpoints, bonds=(), filters=(), name="mavbond", **top) -> Gateway:
        g = Gateway(self.binary, self.workdir, endpoints, bonds, filters, name=name,
                    plugin_dir=self.plugin_dir, log_level="info", **top)
        self.gateways.append(g)
        return g.start()

    def kill(self) -> None:
        for p in self.procs:
            p.stop(5)
        for g in self.gateways:
            g.kill()
        for e in self.emus:
            e.kill()
        for w in self.wires:
            w.close()


def cut_plan(hold: int = 60) -> list:
    """Where the links are cut (tests/peers/cutlinks.py steps). In the middle of each
    transfer, by its own messages as they reach the fast link (the vehicle's: a cut link
    still receives them), the fast link is cut; after `hold` of the vehicle's ATTITUDE
    messages (20 Hz: 3 s, longer than either gateway's linkswitch takes to move) it comes
    back and the slow link is cut instead; `hold` ATTITUDEs later that comes back too. So
    each transfer loses each link in turn while it runs: dedup must carry on over the other
    link; linkswitch must move to the other link and back again. The time a cut lasts is the
    vehicle's telemetry's, so every cut ends whatever becomes of the transfer."""
    def transfer(msgid: int, middle: int) -> list:
        return [
            {"on": {"link": "fast", "dir": "up", "msgid": msgid, "count": middle,
                    "total": True},
             "do": [["cut", "fast"]]},
            {"on": {"link": "fast", "dir": "up", "msgid": ATTITUDE, "count": hold},
             "do": [["restore", "fast"], ["cut", "slow"]]},
            {"on": {"link": "slow", "dir": "up", "msgid": ATTITUDE, "count": hold},
             "do": [["restore", "slow"]]},
        ]
    PARAM_VALUE, MISSION_REQUEST_INT, MISSION_ITEM_INT, FTP = 22, 51, 73, 110
    return (transfer(PARAM_VALUE, 150)            # of 300 parameters
            + transfer(MISSION_REQUEST_INT, 50)   # upload: the vehicle asks for 100 items
            + transfer(MISSION_ITEM_INT, 50)      # download: the vehicle sends 100 items
            + transfer(FTP, 550))                 # 256 KiB: about 1,100 chunks


class Rig:
    """vehicle -- pty wire -- air mavbond == links == ground mavbond -- ground station.

    mode: "clean" (one link, no loss, no bond: the reference), "dedup" or "linkswitch" (two
    lossy links bonded on both gateways, the filter on both). cuts: cutlinks.py steps.
    renumber: the ground bond renumbers (dedup key: content), for a GCS counting loss."""

    def __init__(self, lab: PeerLab, mode: str, cuts: Optional[list] = None, *,
                 params: int = 300, renumber: bool = False, name: Optional[str] = None):
        assert mode in ("clean", "dedup", "linkswitch")
        self.lab, self.mode, self.cuts = lab, mode, cuts or []
        self.name = name or mode
        self.dir = lab.workdir / self.name
        self.dir.mkdir(parents=True, exist_ok=True)
        self.params = params
        self.links = ["clean"] if mode == "clean" else ["fast", "slow"]
        self.ports = {"gcs": free_port()}
        for l in self.links:
            self.ports[f"listen_{l}"] = free_port()
            self.ports[f"ground_{l}"] = free_port()
        self.tlog_dirs = {side: self.dir / f"{side}-tlog" for side in ("air", "ground")}
        self.status = {side: self.dir / f"{side}.sock" for side in ("air", "ground")}
        self.blob = ftp_blob(self.dir / "ftp-root" / "blob.bin")
        self.renumber = renumber
        self.vehicle: Optional[Process] = None
        self.vehicle_summary: Optional[dict] = None
        self.gcs: Optional[Process] = None
        self.wire: Optional[PtyWire] = None
        self.emu: Optional[EmuGroup] = None

    # --- configs -------------------------------------------------------------------------

    def _filters(self, bond: str, side: str) -> List[dict]:
        if self.mode == "dedup":
            # The links are 300 ms apart: a copy the slow link rescues is 300 ms old, so
            # stale_after is set above that (its default, 250 ms, would drop the rescued
            # telemetry samples as stale: by design, and not what is tested here).
            f = {"plugin": "dedup", "bonds": [bond], "stale_after": "1s"}
            if side == "ground" and self.renumber:
                f["key"] = "content"
        elif self.mode == "linkswitch":
            # Its defaults on both sides. What the air side hears from the ground between
            # transfers is the GCS's 1 Hz heartbeat: with switch_after taken literally one lost
            # heartbeat was a dead link, and the bond moved to the slow link for good (found
            # here; linkswitch now waits for three of a link's usual gaps, and fails back to a
            # link too thin to judge).
            f = {"plugin": "linkswitch", "bonds": [bond]}
        else:
            return []
        return [f, {"plugin": "stats", "interval": "1s", "log": False}]

    def start(self) -> "Rig":
        return self.start_links().start_vehicle()

    def start_links(self) -> "Rig":
        """Everything but the vehicle: ground gateway, links, wire, air gateway."""
        lab, p = self.lab, self.ports
        bonded = self.mode != "clean"
        member = {"bond": "vehicle"} if bonded else {}
        ground_eps = [udp_server(l, p[f"ground_{l}"], **member) for l in self.links]
        # The ground station is on TCP: a UDP socket of its default size overflows under a
        # burst (300 parameters at once), and that loss would be the station's, not the
        # bond's. What the gateway holds for it may be a whole FTP burst (36 KB).
        ground_eps += [tcp_server("gcs", p["gcs"], tx_queue="1MiB"),
                       {"name": "log", "type": "tlog", "directory": str(self.tlog_dirs["ground"])}]
        # The evidence knows frames by their bytes in both gateways' tlogs: a bond renumbers
        # only when the run asks (the MAVProxy run, whose loss figure needs it).
        gbond = [{"name": "vehicle", "tx": "broadcast", "renumber": self.renumber}] if bonded else []
        self.ground = lab.gateway(ground_eps, bonds=gbond,
                                  filters=self._filters("vehicle", "ground"),
                                  name=f"{self.name}-ground",
                                  status_socket=str(self.status["ground"]))
        # Each link records every datagram it received (its bytes): the gateways write count
        # markers of their own between the ends' frames, so a datagram's index is not a
        # frame's; the record says which datagram was which (evidence.Direction).
        self.received_logs = {l: self.dir / f"{l}-received.jsonl" for l in self.links}
        spec = [{"name": l, "listen_port": p[f"listen_{l}"], "forward_ports": p[f"ground_{l}"],
                 "seed": SEEDS[l], "log_received": str(self.received_logs[l]),
                 **{"fast": FAST, "slow": SLOW, "clean": CLEAN}[l]}
                for l in self.links]
        self.emu = EmuGroup(lab.workdir, self.name, spec)
        cuts_path = self.dir / "cuts.json"
        cuts_path.write_text(json.dumps(self.cuts))
        self.cut_log = self.dir / "cuts-done.jsonl"
        self.emu.args = [sys.executable, str(HERE / "cutlinks.py"), "--group",
                         str(self.emu.spec_path), "--cuts", str(cuts_path),
                         "--cut-log", str(self.cut_log)]
        lab.emus.append(self.emu)
        self.emu.start()
        self.wire = PtyWire()
        lab.wires.append(self.wire)
        amember = {"bond": "ground"} if bonded else {}
        air_eps = [{"name": "autopilot", "type": "uart", "device": self.wire.paths[1],
                    "baud": BAUD}]
        air_eps += [udp_client(l, p[f"listen_{l}"], **amember) for l in self.links]
        air_eps.append({"name": "log", "type": "tlog", "directory": str(self.tlog_dirs["air"])})
        abond = [{"name": "ground", "tx": "broadcast", "renumber": False}] if bonded else []
        self.air = lab.gateway(air_eps, bonds=abond, filters=self._filters("ground", "air"),
                               name=f"{self.name}-air", status_socket=str(self.status["air"]))
        self.air.wait_log(r"\[uart:autopilot\] .* open at")
        return self

    def start_vehicle(self) -> "Rig":
        self.vehicle = Process(self.dir, "vehicle", [
            sys.executable, str(HERE / "mavsdk_vehicle.py"),
            "--url", f"serial://{self.wire.paths[0]}:{BAUD}", "--params", str(self.params),
            "--ftp-root", str(self.blob.parent), "--timeout", str(MAVSDK_TIMEOUT),
            "--max-seconds", "400"])
        self.lab.procs.append(self.vehicle)
        self.vehicle.wait_line("event", "ready", 30)
        # The ground gateway knows each link's peer (the emulator) once the vehicle's first
        # frames came up it: only then does what the ground station sends go down every link.
        deadline = time.monotonic() + 20
        while True:
            c = self.emu.counters_now()
            if all(c[l]["up"]["forwarded"] > 0 for l in self.links):
                break
            assert time.monotonic() < deadline, f"no vehicle traffic on the links: {c}"
            time.sleep(0.1)
        return self

    # --- ground stations ---------------------------------------------------------------------

    def run_mavsdk_gcs(self, limit: float = 300.0) -> dict:
        """The MAVSDK ground station's workload; {"rc", "steps": {step: its line}, "tail"}."""
        self.gcs = Process(self.dir, "gcs", [
            sys.executable, str(HERE / "mavsdk_gcs.py"),
            "--url", f"tcpout://{HOST}:{self.ports['gcs']}", "--params", str(self.params),
            "--mission", "100", "--ftp-file", "/blob.bin", "--ftp-expect", str(self.blob),
            "--download-dir", str(self.dir / "download"), "--timeout", str(MAVSDK_TIMEOUT),
            "--step-limit", "120"])
        self.lab.procs.append(self.gcs)
        rc = self.gcs.wait(limit)
        if rc is None:
            self.gcs.stop()
        return {"rc": rc, "steps": {d["step"]: d for d in self.gcs.lines()},
                "tail": self.gcs.tail()}

    # --- the end -------------------------------------------------------------------------

    def stop_vehicle(self) -> None:
        """Stops the vehicle and waits until the links carry nothing more."""
        if self.vehicle is not None and self.vehicle_summary is None:
            self.vehicle.stop()
            self.vehicle_summary = next((d for d in self.vehicle.lines()
                                         if d.get("event") == "summary"), {})
        deadline = time.monotonic() + 10
        while any(c[d]["in_flight"] for c in self.emu.counters_now().values()
                  for d in ("up", "down")):
            assert time.monotonic() < deadline, "the links never emptied"
            time.sleep(0.05)

    def finish(self) -> None:
        """Stops the ground station; once every cut step was taken (they follow the vehicle's
        telemetry, so they are, seconds later), the vehicle; lets the links empty, reads both
        status sockets, stops the gateways (their tlogs are then complete) and the emulator;
        keeps the gateways' counters at exit (`exit_stats`)."""
        if self.gcs is not None:
            self.gcs.stop()
        deadline = time.monotonic() + 30
        while self.cuts and len(self.cuts_taken()) < len(self.cuts):
            if time.monotonic() > deadline:
                break
            time.sleep(0.1)
        self.stop_vehicle()
        self.status_docs = {side: status_document(path) for side, path in self.status.items()}
        for g in (self.air, self.ground):
            assert g.stop() == 0, g.log()[-3000:]
        self.exit_stats = {side: exit_stats(g) for side, g in
                           (("air", self.air), ("ground", self.ground))}
        self.emu_counters = self.emu.stop()
        self.wire.close()
        self.cuts_done = self.cuts_taken()

    def frames_so_far(self, link: str, direction: str = "up") -> int:
        """The frames (datagrams that are no count marker) `link` has received so far in
        `direction`, from its record of what it received, which counters_now() has it write
        out; read while it is still being written, what the record holds so far: never more
        than came."""
        from evidence import link_marker
        self.emu.counters_now()
        text = self.received_logs[link].read_text()
        return sum(1 for line in text[:text.rfind("\n") + 1].splitlines()
                   if (r := json.loads(line))["direction"] == direction
                   and link_marker(bytes.fromhex(r["data"]), link) is None)

    def cuts_taken(self) -> List[dict]:
        if not self.cut_log.exists():
            return []
        text = self.cut_log.read_text()
        return [json.loads(l) for l in text[:text.rfind("\n") + 1].splitlines() if l]

    def dropped_inside(self) -> Dict[str, dict]:
        """Endpoints that dropped or lost frames inside a gateway (a full transmit queue, an
        overflowing socket, bytes that were no frame), from the counters at exit: then a
        frame in a tlog was not really delivered, or one sent never got in."""
        out = {}
        for side, eps in self.exit_stats.items():
            for name, c in eps.items():
                bad = {k: c.get(k, 0) for k in ("tx_dropped", "tx_errors", "rx_overflows",
                                                  "crc_errors", "garbage_bytes")
                       if c.get(k, 0)}
                if bad:
                    out[f"{side}:{name}"] = bad
        return out


def exit_stats(g: Gateway) -> Dict[str, dict]:
    """{endpoint: counters} from the lines a gateway logs when it stops (a TCP server's
    clients are endpoints of their own, "gcs@127.0.0.1:PORT")."""
    from helpers import parse_stats
    log = g.log()
    tail = log[log.rfind("stopping"):]
    return {d["endpoint"]: d for d in parse_stats(tail)}


def status_document(path: Path, timeout: float = 5.0) -> dict:
    import socket
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(str(path))
        data = b""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    return json.loads(data)


# --- the evidence ----------------------------------------------------------------------------

def link_drops(emu: EmuGroup, link: str, direction: str) -> set:
    """Datagram indices a link did not deliver (lost, or cut: 'outage')."""
    return emu.dropped(link, direction)


def link_datagrams(rig: Rig, link: str, direction: str) -> List[bytes]:
    """Every datagram a link received in one direction, in index order (the emulator's record
    of what it received, written as it stopped)."""
    out = []
    for line in rig.received_logs[link].read_text().splitlines():
        r = json.loads(line)
        if r["direction"] == direction:
            assert r["index"] == len(out), f"{link} {direction}: the record skips to {r['index']}"
            out.append(bytes.fromhex(r["data"]))
    return out


def gather(rig: Rig, renumbered: bool = False, steps: Optional[dict] = None,
           directions=("up", "down")) -> dict:
    """Both directions accounted and every protocol's retries judged, from the rig's logs;
    steps: the ground station's step lines (for the transfers it had to start again)."""
    from evidence import (Direction, frames_of, protocols, read_log, repeats)
    air, ground = read_log(rig.tlog_dirs["air"]), read_log(rig.tlog_dirs["ground"])
    out = {}

    def links(direction: str) -> dict:
        return dict(dropped={l: link_drops(rig.emu, l, direction) for l in rig.links},
                    datagrams={l: link_datagrams(rig, l, direction) for l in rig.links},
                    counted={l: rig.emu_counters[l][direction]["received"] for l in rig.links})

    if "up" in directions:
        out["up"] = Direction("vehicle -> GCS", frames_of(air, VEHICLE), frames_of(ground, VEHICLE),
                              renumbered=renumbered, **links("up")).account()
    if "down" in directions:
        out["down"] = Direction("GCS -> vehicle", frames_of(ground, GCS), frames_of(air, GCS),
                                **links("down")).account()
    if len(out) == 2:
        attempts = {name: d["attempts"] for name, d in (steps or {}).items()
                    if name in ("params", "mission_upload", "mission_download", "ftp")
                    and len(d.get("attempts", ())) > 1}
        out["attempts"] = attempts
        out["retries"] = protocols(out["down"].sent, out["up"].sent, fast="fast",
                                   attempts=attempts)
        out["repeats"] = repeats(out["up"].sent, out["down"].sent)
    return out
