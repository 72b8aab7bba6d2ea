"""The SITL rig: a real autopilot behind the shipped example pair, with link models that
record the truth and MAVProxy as the ground station.

  ArduCopter SITL --pty-- wire --pty-- air mavbond (conf/examples/air-side.yaml)
      --pty-- SiK radio model --pty--  \\
      --udp-- LTE model (linkemu) --udp-- ground mavbond (conf/examples/ground-side.yaml)
                                            --tcp-- MAVProxy (its `mavproxy` endpoint)

The links are tests/sitl/linkmodels.py (one process): the wire between SITL's UART and the
air gateway's, the SiK radio pair, the LTE link; each records what it carried and dropped.
The gateways run the shipped examples changed only by OVERLAY (device paths, addresses, file
paths; plugin_dir is given as --plugin-dir): apply_overlay() makes the change and refuses any
other difference. ArduCopter SITL comes from ../shared/sitl next to the checkout (or
MAVBOND_SITL_DIR), never copied into the project; without it every user of the rig skips."""
from __future__ import annotations

import difflib
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
sys.path.insert(0, str(REPO / "tests" / "peers"))

from helpers import Daemon, free_port, status_document, terminate  # noqa: E402
from mavproxy import MAVProxy  # noqa: E402

EXAMPLES = REPO / "conf" / "examples"
HOME = "-35.363261,149.165230,584,353"     # ArduPilot's autotest home (CMAC)


# --- ArduCopter SITL ---------------------------------------------------------------------------

def sitl_dir() -> Path:
    """Where ArduCopter SITL is looked for: ../shared/sitl next to the checkout, or
    MAVBOND_SITL_DIR."""
    return Path(os.environ.get("MAVBOND_SITL_DIR", REPO.parent / "shared" / "sitl"))


def require_sitl() -> Path:
    d = sitl_dir()
    if not (d / "bin" / "arducopter").is_file():
        pytest.skip(f"no ArduCopter SITL at {d}/bin/arducopter (the shared directory next to "
                    f"the checkout, or MAVBOND_SITL_DIR): the SITL rig cannot run")
    return d


def listening_ports(pid: int) -> List[Tuple[str, int]]:
    """(protocol, port) of every socket of `pid` bound to a port, from /proc."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for proto in ("tcp", "udp", "tcp6", "udp6"):
        try:
            rows = Path(f"/proc/net/{proto}").read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            port = int(cols[1].rsplit(":", 1)[1], 16)
            if cols[9] in inodes and port:
                out.append((proto, port))
    return sorted(set(out))


class Sitl:
    """ArduCopter SITL in its own directory: SERIAL1 (TELEM1, as a flight controller's on a
    companion computer) is the UART at `uart` (a pty), SERIAL0 and SERIAL2 (TCP 5760 and 5763
    + 10 x instance by default; SERIAL0 also carries the console) are switched off, its RC input
    (UDP on every interface, 5501 + 10 x instance by default) is put on `rc_port`, a port of
    the run's range: then it listens on nothing else (checked by ports()). `blob` is put in
    its directory, the root of its MAVLink FTP."""

    def __init__(self, workdir: Path, uart: str, instance: int, rc_port: int,
                 blob: Optional[bytes] = None):
        self.dir = workdir
        self.dir.mkdir(parents=True, exist_ok=True)
        d = require_sitl()
        if blob is not None:
            (self.dir / "blob.bin").write_bytes(blob)
        self.rc_port = rc_port
        self.argv = [str(d / "bin" / "arducopter"), "--model", "+", "--speedup", "1",
                     "--slave", "0", "--defaults", str(d / "params" / "copter.parm"),
                     "--sim-address=127.0.0.1", "-I", str(instance), "-w", "--home", HOME,
                     "--serial0=none", f"--serial1=uart:{uart}:921600", "--serial2=none",
                     "--rc-in-port", str(rc_port)]
        self.log_path = self.dir / "sitl.out"
        self.proc: Optional[subprocess.Popen] = None

    def start(self) -> "Sitl":
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(self.argv, cwd=self.dir, stdin=subprocess.DEVNULL,
                                     stdout=self._log, stderr=subprocess.STDOUT)
        self.started = time.monotonic()
        return self

    def ports(self) -> List[Tuple[str, int]]:
        return listening_ports(self.proc.pid)

    def stop(self) -> Optional[int]:
        code = terminate(self.proc)
        if self.proc is not None:
            self._log.close()
        return code


# --- the link models ---------------------------------------------------------------------------

class LinkModels:
    """tests/sitl/linkmodels.py as a process: its banner, its commands, its records."""

    def __init__(self, workdir: Path, lte_listen: int, ground_lte: int, seed: int):
        self.dir = workdir / "links"
        self.dir.mkdir(parents=True, exist_ok=True)
        spec = self.dir / "spec.json"
        spec.write_text(json.dumps({"seed": seed, "lte": {
            "listen": f"127.0.0.1:{lte_listen}", "forward": f"127.0.0.1:{ground_lte}"}}))
        self.err = open(self.dir / "linkmodels.err", "wb")
        self.proc = subprocess.Popen(
            [sys.executable, str(HERE / "linkmodels.py"), "--spec", str(spec), "--records",
             str(self.dir)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.err)
        self.banner = self._reply()
        (self.dir / "banner.json").write_text(json.dumps(self.banner))   # its clocks

    def _reply(self, timeout: float = 20.0) -> dict:
        import select
        r, _, _ = select.select([self.proc.stdout], [], [], timeout)
        assert r, f"the link models said nothing: {(self.dir / 'linkmodels.err').read_text()}"
        line = self.proc.stdout.readline()
        assert line, f"the link models exited: {(self.dir / 'linkmodels.err').read_text()}"
        return json.loads(line)

    def command(self, cmd: str) -> dict:
        self.proc.stdin.write((cmd + "\n").encode())
        self.proc.stdin.flush()
        reply = self._reply()
        assert reply.get("done") == cmd, reply
        return reply

    def stop(self) -> dict:
        if self.proc.poll() is None:
            self.proc.stdin.write(b"stop\n")
            self.proc.stdin.flush()
            self.final = self._reply(60)
            self.proc.wait(30)
        self.err.close()
        return self.final

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if not self.err.closed:
            self.err.close()


# --- the shipped examples and the overlay ------------------------------------------------------

# What the rig changes in the shipped examples, and nothing else: where the devices are, the
# addresses (loopback ports of the run's range instead of the examples' public ones) and the
# files the examples leave commented out (status_socket) or do not have (metrics: the
# examples serve no /metrics). plugin_dir is the build tree's, given as --plugin-dir.
# Keys: (endpoint name, key) or (top-level key,).
def overlay_for(side: str, r: "Rig") -> Dict[tuple, str]:
    common = {("status_socket",): str(r.status[side]),
              ("vehicle", "key_file"): str(r.key_file),
              ("metrics",): f"{{listen: \"127.0.0.1:{r.ports['metrics_' + side]}\"}}"}
    if side == "air":
        return {("autopilot", "device"): r.ptys["autopilot"],
                ("sik", "device"): r.ptys["radio_air"],
                ("lte", "address"): f"127.0.0.1:{r.ports['lte_listen']}", **common}
    return {("sik", "device"): r.ptys["radio_ground"],
            ("lte", "address"): f"127.0.0.1:{r.ports['ground_lte']}",
            ("qgc", "address"): f"127.0.0.1:{r.ports['qgc']}",
            ("mavproxy", "address"): f"127.0.0.1:{r.ports['mavproxy']}", **common}


OVERLAY_DOC = [
    ("air", "autopilot.device", "the pty of the wire to SITL's SERIAL1"),
    ("air", "sik.device", "the air radio model's pty"),
    ("air", "lte.address", "the LTE model's listening port (127.0.0.1)"),
    ("ground", "sik.device", "the ground radio model's pty"),
    ("ground", "lte.address", "127.0.0.1 and a port of the run's range (the LTE model sends there)"),
    ("ground", "qgc.address", "127.0.0.1 and a port of the run's range"),
    ("ground", "mavproxy.address", "127.0.0.1 and a port of the run's range (MAVProxy connects)"),
    ("both", "status_socket", "uncommented, a file in the run's directory"),
    ("both", "vehicle.key_file", "the bond's key, made once per run by mavbondctl keygen"),
    ("both", "metrics", "added: {listen: 127.0.0.1:PORT} (the examples serve no /metrics)"),
]

_VALUE = r"(\"[^\"]*\"|'[^']*'|[^\s#]+)"


def apply_overlay(text: str, edits: Dict[tuple, str]) -> str:
    """The example's text with each edit made in place (its line keeps its comment), and
    nothing else changed: a difference other than the edits' lines fails."""
    lines = text.split("\n")
    touched = set()
    for key, value in edits.items():
        if len(key) == 2:
            name, k = key
            start = next(i for i, l in enumerate(lines)
                         if re.match(rf"^\s*- name:\s*{re.escape(name)}\b", l))
            end = next((i for i in range(start + 1, len(lines))
                        if re.match(r"^\s*- name:|^\S", lines[i])), len(lines))
            i = next(i for i in range(start, end)
                     if re.match(rf"^\s*(- )?{re.escape(k)}:", lines[i]))
            lines[i] = re.sub(rf"^(\s*(?:- )?{re.escape(k)}:\s*){_VALUE}",
                              lambda m: m.group(1) + value, lines[i], count=1)
        else:
            (k,) = key
            i = next((i for i, l in enumerate(lines) if re.match(rf"^#?\s*{k}:", l)), None)
            if i is None:       # a key the example does not have: before the endpoints
                i = lines.index("endpoints:")
                lines.insert(i, f"{k}: {value}")
            else:
                lines[i] = f"{k}: {value}" + (
                    "   " + lines[i][lines[i].index("#", 1):] if "#" in lines[i][1:] else "")
        touched.add(i)
    out = "\n".join(lines)
    changed = [l for l in difflib.unified_diff(text.split("\n"), lines, lineterm="", n=0)
               if l[:1] in "+-" and not l.startswith(("+++", "---"))]
    assert sum(1 for l in changed if l.startswith("+")) == len(edits), \
        f"the overlay changed more than its {len(edits)} lines: {changed}"
    return out


# --- the rig -----------------------------------------------------------------------------------

@dataclass
class Snapshot:
    """What the operator's tools showed at one moment: both gateways' status documents,
    `mavbondctl watch --count 1` and /metrics, with the time (time.monotonic())."""
    label: str
    t: float
    status: Dict[str, dict]
    watch: Dict[str, str]
    metrics: Dict[str, str]


class Rig:
    """One SITL rig in `workdir`: start() brings up the links, both gateways and SITL; gcs()
    starts a MAVProxy on the ground gateway; cut()/restore()/rebind()/reload() change the
    world; snapshot() reads what the operator's tools show; stop() ends everything and
    leaves the records (links/*.jsonl, the MAVProxy tlogs and outputs, the gateways' logs)."""

    def __init__(self, workdir: Path, binary: str, plugin_dir: str, name: str, seed: int = 1,
                 blob: Optional[bytes] = None):
        self.dir = workdir / name
        self.dir.mkdir(parents=True, exist_ok=True)
        self.binary, self.plugin_dir, self.name, self.seed = binary, plugin_dir, name, seed
        self.blob = blob
        self.ports = {k: free_port() for k in ("lte_listen", "ground_lte", "qgc", "mavproxy",
                                               "metrics_air", "metrics_ground", "rc")}
        # SITL's instance: distinct for every rig that runs at once (its RC port is unique).
        self.instance = self.ports["rc"] % 200
        self.status = {side: self.dir / f"{side}.sock" for side in ("air", "ground")}
        self.gateways: Dict[str, Daemon] = {}
        self.models: Optional[LinkModels] = None
        self.sitl: Optional[Sitl] = None
        self.gcses: List[MAVProxy] = []
        self.snapshots: List[Snapshot] = []
        self.sitl_listening: List[Tuple[str, int]] = []

    def start(self) -> "Rig":
        self.models = LinkModels(self.dir, self.ports["lte_listen"], self.ports["ground_lte"],
                                 self.seed)
        self.ptys = self.models.banner["ptys"]
        self.clock = (self.models.banner["mono"], self.models.banner["wall"])
        # The bond's key, made as the examples say (mavbondctl keygen), one file for both sides.
        self.key_file = self.dir / "bond.key"
        if not self.key_file.exists():
            subprocess.run([str(Path(self.binary).with_name("mavbondctl")), "keygen",
                            str(self.key_file)], check=True, capture_output=True)
        for side in ("ground", "air"):
            text = (EXAMPLES / f"{side}-side.yaml").read_text()
            config = apply_overlay(text, overlay_for(side, self))
            d = Daemon(self.binary, self.dir, config, name=f"{side}-mavbond",
                       extra_args=["--plugin-dir", self.plugin_dir])
            self.gateways[side] = d
            d.start(timeout=15)
        self.gateways["air"].wait_log(r"\[uart:autopilot\] .* open at", timeout=10)
        self.sitl = Sitl(self.dir / "sitl", self.ptys["sitl"], self.instance,
                         self.ports["rc"], self.blob).start()
        deadline = time.monotonic() + 10
        while not self.sitl.ports() and time.monotonic() < deadline:
            time.sleep(0.1)
        self.sitl_listening = self.sitl.ports()
        return self

    def gcs(self, name: str) -> MAVProxy:
        """MAVProxy as it starts (its default modules and stream rate), on the ground
        gateway's MAVProxy port, its telemetry log flushed as it goes."""
        mp = MAVProxy(self.dir / name, f"tcp:127.0.0.1:{self.ports['mavproxy']}",
                      [f"--logfile={self.dir / name / 'mav.tlog'}",
                       f"--state-basedir={self.dir / name}"], name="mavproxy")
        self.gcses.append(mp)
        mp.send("set flushlogs 1")
        return mp

    def cut(self, link: str) -> float:
        return self.models.command(f"cut {link}")["t"]

    def restore(self, link: str) -> float:
        return self.models.command(f"restore {link}")["t"]

    def rebind(self) -> dict:
        return self.models.command("rebind lte")

    def reload(self, side: str) -> float:
        d = self.gateways[side]
        n = d.log().count("reloaded: ")
        t = time.monotonic()
        d.proc.send_signal(signal.SIGHUP)
        d.wait_log(r"reloaded: ", count=n + 1, timeout=10)
        return t

    def snapshot(self, label: str) -> Snapshot:
        ctl = str(Path(self.binary).with_name("mavbondctl"))
        t = time.monotonic()
        status, watch, metrics = {}, {}, {}
        for side in ("air", "ground"):
            status[side] = status_document(self.status[side])
            watch[side] = subprocess.run([ctl, "-s", str(self.status[side]), "watch", "--count",
                                          "1"], capture_output=True, text=True,
                                         timeout=30).stdout
            with urllib.request.urlopen(
                    f"http://127.0.0.1:{self.ports['metrics_' + side]}/metrics", timeout=10) as r:
                metrics[side] = r.read().decode()
        s = Snapshot(label, t, status, watch, metrics)
        self.snapshots.append(s)
        (self.dir / "snapshots").mkdir(exist_ok=True)
        (self.dir / "snapshots" / f"{len(self.snapshots):02d}.json").write_text(
            json.dumps(s.__dict__, indent=1))
        return s

    def stop(self) -> None:
        """Ground stations, SITL, then the links once they carry nothing more, then the
        gateways (their exit counters in their logs), then the link models' records."""
        for mp in self.gcses:
            mp.stop()
        if self.sitl is not None and self.sitl.proc.poll() is None:
            self.sitl_listening = sorted(set(self.sitl_listening) | set(self.sitl.ports()))
            self.sitl.stop()
        time.sleep(3.0)       # what the radio's buffer and the LTE delay still hold
        for d in self.gateways.values():
            d.stop(timeout=10)
        if self.models is not None:
            self.models.stop()

    def kill(self) -> None:
        for mp in self.gcses:
            mp.stop()
        if self.sitl is not None:
            self.sitl.stop()
        for d in self.gateways.values():
            d.kill()
        if self.models is not None:
            self.models.kill()
