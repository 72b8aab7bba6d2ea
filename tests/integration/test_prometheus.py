"""Debian's Prometheus server (not a parser of ours) scraping a real mavbond with the scrape
config shipped in conf/examples: the target is up with no scrape error, every metric family
mavbond(8) documents is stored, a PromQL query of every series returns what the daemon serves
and what its status socket shows, and every Grafana dashboard query evaluates without error.

scripts/setup.sh installs the prometheus package; without it the test skips and says so."""
from __future__ import annotations

import calendar
import json
import os
import re
import shutil
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from helpers import HOST, REPO, FrameMaker, free_port, status_document, uart, udp_server
from synth import ardupilot_stream
from test_metrics import DASHBOARD, scrape, tcp_port, value

PROMETHEUS = shutil.which("prometheus") or "/usr/bin/prometheus"
SCRAPE_CONFIG = REPO / "conf" / "examples" / "prometheus-mavbond.yml"
MANUAL = REPO / "conf" / "man" / "mavbond.8.in"
# Series whose value moves between two reads of a quiet daemon: its clock, the age of its last
# frame, and the HTTP endpoint's own counters (every scrape adds to them).
# Figures that move with the clock: a bond's RADIO_STATUS (once a second while a member
# reports or hears), a metered bond's standby reports (one a second) and its state (its peer,
# the test, reports once and then falls silent).
MOVING = re.compile(r"^mavbond_(uptime_seconds|endpoint_last_rx_age_seconds|metrics_http_\w+|"
                    r"bond_radio_status_sent_total|standby_\w+)$")

pytestmark = pytest.mark.skipif(
    not Path(PROMETHEUS).is_file(),
    reason="Debian's prometheus is not installed (scripts/setup.sh installs it as root)")


def documented_families() -> set:
    """Every metric name in mavbond(8)'s METRICS section: the tag lines of its list (`.TP` and
    `.TQ`), roff escapes removed, `{a,b}` expanded and `COUNTER` replaced by the counters that
    entry lists in bold."""
    text = MANUAL.read_text()
    section = text[text.index("\n.SH METRICS\n") + 1:]
    section = section[:section.index("\n.SH ")]
    names = set()
    for entry in re.split(r"^\.TP\n", section, flags=re.M)[1:]:
        lines = entry.splitlines()
        tags = [lines[0]] + [lines[i + 1] for i, line in enumerate(lines[:-1]) if line == ".TQ"]
        body = "\n".join(line for line in lines[1:] if line not in tags and line != ".TQ")
        counters = re.findall(r"\\fB([a-z_]+)\\f[RP]", body)
        for tag in tags:
            tag = re.sub(r"\\f[BIRP]|\\[:%&]", "", tag)
            for pattern in re.findall(r"mavbond_(?:[A-Za-z_]|\{[^}]*\})+", tag):
                expanded = [pattern]
                while any("{" in p or "COUNTER" in p for p in expanded):
                    nxt = []
                    for p in expanded:
                        if "COUNTER" in p:
                            assert counters, f"{tag}: no counters listed"
                            nxt += [p.replace("COUNTER", c) for c in counters]
                        elif m := re.search(r"\{([^}]*)\}", p):
                            nxt += [p[:m.start()] + alt + p[m.end():]
                                    for alt in m.group(1).split(",")]
                        else:
                            nxt.append(p)
                    expanded = nxt
                names |= set(expanded)
    return names


def same(a, b) -> bool:
    """Equal figures, NaN equal to NaN (linkswitch's loss before it judged a link)."""
    return a == b or (a != a and b != b)


class Prometheus:
    """prometheus itself, with the shipped scrape config pointed at `target` and scraping
    every second (the only two changes), its storage and web port in `workdir`."""

    def __init__(self, workdir: Path, target: str):
        self.port = free_port()
        shipped = SCRAPE_CONFIG.read_text()
        assert "'127.0.0.1:9273'" in shipped and "scrape_interval: 5s" in shipped
        config = workdir / "prometheus.yml"
        config.write_text(shipped.replace("'127.0.0.1:9273'", f"'{target}'")
                          .replace("scrape_interval: 5s", "scrape_interval: 1s")
                          .replace("scrape_timeout: 4s", "scrape_timeout: 1s"))
        self.log_path = workdir / "prometheus.log"
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [PROMETHEUS, f"--config.file={config}", f"--storage.tsdb.path={workdir / 'tsdb'}",
             f"--web.listen-address={HOST}:{self.port}", "--log.level=warn"],
            stdout=self.log, stderr=subprocess.STDOUT)

    def api(self, path: str, **params) -> dict:
        url = f"http://{HOST}:{self.port}/api/v1/{path}"
        if params:
            url += "?" + urllib.parse.urlencode(params)
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                doc = json.load(r)
        except urllib.error.HTTPError as e:  # a bad query: 400 with the error as JSON
            doc = json.load(e)
        return doc

    def wait_ready(self, timeout: float = 60.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, f"prometheus exited: {self.log_path.read_text()}"
            try:
                with urllib.request.urlopen(f"http://{HOST}:{self.port}/-/ready", timeout=2):
                    return
            except OSError:
                time.sleep(0.2)
        raise AssertionError(f"prometheus not ready in {timeout}s: {self.log_path.read_text()}")

    def scraped_after(self, instant: float, timeout: float = 30.0) -> dict:
        """The mavbond target once a scrape that began after `instant` (epoch s) succeeded."""
        deadline = time.monotonic() + timeout
        target = None
        while time.monotonic() < deadline:
            targets = self.api("targets")["data"]["activeTargets"]
            target = next((t for t in targets if t["scrapePool"] == "mavbond"), None)
            last = target["lastScrape"] if target else "0001"
            if target and target["health"] == "up" and not last.startswith("0001"):
                # RFC 3339 in UTC with nanoseconds: whole seconds are enough here
                t = calendar.timegm(time.strptime(last[:19], "%Y-%m-%dT%H:%M:%S"))
                if t > instant + 1:
                    return target
            time.sleep(0.25)
        raise AssertionError(f"no good scrape after the traffic in {timeout}s: {target}")

    def query(self, expr: str) -> list:
        doc = self.api("query", query=expr)
        assert doc["status"] == "success", (expr, doc)
        return doc["data"]["result"]

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


def test_prometheus_stores_what_the_daemon_and_its_status_socket_show(lab, pty_pair, tmp_path):
    """One vehicle's stream into a gateway with every kind of figure: a broadcast bond with
    dedup (by content) and renumbering, an active-link bond with linkswitch, stats over both, a
    transmit budget on the GCS server, a SiK radio on a UART that reports, a bond with a
    metered member whose peer (the test) sends it one link loss report, a signed bond (its
    counters, at 0). Once the traffic is
    over and Prometheus has scraped
    again, each documented family is stored, each
    series Prometheus holds has the value /metrics serves, and the status socket's counters
    come back from PromQL unchanged."""
    ports = {k: free_port() for k in ("a1", "a2", "b1", "b2", "m1", "m2", "s1", "gcs")}
    m_port = tcp_port()
    status_path = tmp_path / "status.sock"
    radio = pty_pair()
    key = tmp_path / "bond.key"
    key.write_text(os.urandom(32).hex() + "\n")
    key.chmod(0o600)
    g = lab.gateway([udp_server("a1", ports["a1"], bond="bonded"),
                     udp_server("a2", ports["a2"], bond="bonded"),
                     udp_server("b1", ports["b1"], bond="backup"),
                     udp_server("b2", ports["b2"], bond="backup"),
                     # its peer (the test) forgotten a second after its report: the gateway's
                     # own reports to it stop, and its figures settle
                     udp_server("m1", ports["m1"], bond="paid", peer_timeout="1s"),
                     udp_server("m2", ports["m2"], bond="paid", cost="metered",
                                peer_timeout="1s"),
                     udp_server("s1", ports["s1"], bond="signed"),
                     udp_server("gcs", ports["gcs"], tx_rate="1MB/s"),
                     uart("r1", radio.path, baud=57600, radio_status="sik", bond="radio")],
                    bonds=[{"name": "bonded", "tx": "broadcast", "renumber": True},
                           {"name": "backup", "tx": "active"}, {"name": "radio"},
                           {"name": "paid", "tx": "broadcast"},
                           {"name": "signed", "signing": f"{{key_file: {key}}}"}],
                    filters=[{"plugin": "dedup", "bonds": ["bonded"], "key": "content"},
                             {"plugin": "linkswitch", "bonds": ["backup"]},
                             {"plugin": "stats"}],
                    status_socket=str(status_path), metrics=f"{{listen: {HOST}:{m_port}}}")
    prom = Prometheus(tmp_path, f"{HOST}:{m_port}")
    try:
        prom.wait_ready()
        src = lab.sock()
        sik = FrameMaker(51, 68, v1=True)
        radio.write_all(sik.pack(sik.mod.MAVLink_radio_status_message(150, 140, 95, 40, 35, 3, 1)))
        frames = [f for _, f in ardupilot_stream(2, seed=5)]
        for i, f in enumerate(frames):
            # every frame on both links of each bond, one in ten lost on a1 and on b2
            for k in ("a1", "a2", "b1", "b2"):
                if not (i % 10 == 3 and k in ("a1", "b2")):
                    src.sendto(f, (HOST, ports[k]))
            if i % 20 == 0:
                time.sleep(0.01)
        # The metered bond's peer reports its free link m1 at 2% loss, over both links.
        fm = FrameMaker(1, 191)
        report = fm.pack(fm.mod.MAVLink_named_value_int_message(0, b"mbl:m1", 20))
        for k in ("m1", "m2"):
            src.sendto(report, (HOST, ports[k]))
        # The daemon's own counters say when the last frame went through.
        lost = len(range(3, len(frames), 10))
        want = {"a1": len(frames) - lost, "a2": len(frames), "b1": len(frames),
                "b2": len(frames) - lost}
        deadline = time.monotonic() + 10
        while True:
            m = scrape(m_port)
            rx = {k: value(m, "mavbond_endpoint_rx_frames_total", endpoint=k, kind="udp-server",
                           bond="bonded" if k[0] == "a" else "backup") for k in want}
            heard = value(m, "mavbond_standby_reports_received_total", bond="paid")
            if rx == want and heard == 2:
                break
            assert time.monotonic() < deadline, f"the gateway took {rx} of {want} frames, {heard} reports"
            time.sleep(0.1)
        # Some figures still move after the traffic (linkswitch judges the links silent), so
        # the comparison takes a Prometheus scrape that fell between two reads of the daemon
        # that agree on every series: what Prometheus stored is then what the daemon served.
        for _ in range(10):
            served = scrape(m_port)
            st = status_document(status_path)
            target = prom.scraped_after(time.time())
            again = scrape(m_port)
            changed = [k for k, v in served["samples"].items() if not MOVING.match(k[0])
                       and not same(again["samples"].get(k), v)]
            if not changed and served["samples"].keys() == again["samples"].keys():
                break
            print(f"still moving: {changed[:5]}")
        else:
            raise AssertionError(f"the daemon's figures did not settle: {changed[:10]}")
        assert target["lastError"] == "", target
        print(f"\nprometheus scraped {target['scrapeUrl']} in {target['lastScrapeDuration']:.4f} s;"
              f" {len(served['samples'])} series served")

        # Every documented family is stored (a counter family under its _total name).
        stored = set(prom.api("label/__name__/values")["data"])
        documented = documented_families()
        assert len(documented) > 60, sorted(documented)
        print(f"{len(documented)} documented families, each stored")
        missing = {n for n in documented if n not in stored and n + "_total" not in stored}
        assert not missing, f"documented but not stored by Prometheus: {sorted(missing)}"

        # Every series served has the same value in Prometheus (NaN stays NaN).
        compared = 0
        for (name, labels), v in served["samples"].items():
            if MOVING.match(name):
                continue
            sel = ",".join(f'{k}="{val}"' for k, val in labels)
            (result,) = prom.query(f"{name}{{{sel}}}")
            got = float(result["value"][1])
            assert same(got, v), (name, labels, got, v)
            compared += 1
        print(f"{compared} series equal in Prometheus and /metrics")

        # The status socket's figures, read back through PromQL.
        for ep in st["endpoints"]:
            for k, v in ep.items():
                if isinstance(v, int) and not isinstance(v, bool) and k != "last_rx_ms_ago":
                    (r,) = prom.query(f'mavbond_endpoint_{k}_total{{endpoint="{ep["name"]}"}}')
                    assert float(r["value"][1]) == v, (ep["name"], k)
            for c, counters in ep.get("tx_budget", {}).items():
                for k, v in counters.items() if c != "rate" else ():
                    (r,) = prom.query(f'mavbond_endpoint_tx_class_{k}_total'
                                      f'{{endpoint="{ep["name"]}",class="{c}"}}')
                    assert float(r["value"][1]) == v, (ep["name"], c, k)
        for b in st["bonds"]:
            (r,) = prom.query(f'mavbond_bond_switches_total{{bond="{b["name"]}"}}')
            assert float(r["value"][1]) == b["switches"]
            for k, v in b.get("renumber", {}).items():
                (r,) = prom.query(f'mavbond_renumber_{k}_total{{bond="{b["name"]}"}}')
                assert float(r["value"][1]) == v, (b["name"], k)
            if "standby" in b:
                (r,) = prom.query(f'mavbond_standby_reports_received_total{{bond="{b["name"]}"}}')
                assert float(r["value"][1]) == b["standby"]["reports_received"] == 2
        filters = {f["name"]: f["status"] for f in st["filters"]}
        (bond,) = [b for b in filters["stats"]["bonds"] if b["name"] == "bonded"]
        (r,) = prom.query('mavbond_stats_bond_delivered_frames_total{bond="bonded"}')
        assert float(r["value"][1]) == bond["delivered"] == len(frames)
        dups = sum(float(r["value"][1]) for r in
                   prom.query('mavbond_dedup_duplicates_total{bond="bonded"}'))
        assert dups == sum(link["duplicates"] for link in filters["dedup"]["links"])
        assert dups == len(frames) - lost  # every copy that came second

        # Every dashboard query evaluates, over the window the traffic ran in, and no series it
        # gives carries a peer's address (a label stays when a NAT moves the peer's port).
        d = json.loads(DASHBOARD.read_text())
        answered = set()
        for p in d["panels"]:
            for t in p.get("targets", []):
                expr = (t["expr"].replace("$__rate_interval", "1m")
                        .replace("$instance", ".*").replace("$bond", ".*"))
                for series in prom.query(expr):
                    answered.add(p["title"])
                    assert not any("@" in v for v in series["metric"].values()), (p["title"], series)
        # The panels of what this daemon has: each link's loss, link states, standby, budgets,
        # the radio's signal, silence.
        assert {"Loss: each link against the delivered (bonded) stream", "Link state", "Standby",
                "Transmit budgets", "Radio RSSI and buffer", "Link silence"} <= answered, answered
        assert g.alive()
    finally:
        prom.stop()
