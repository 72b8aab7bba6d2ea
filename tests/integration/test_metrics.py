"""The Prometheus endpoint (metrics: listen:) of a real mavbond: what it serves, parsed by an
independent parser (prometheus_client's), checked against the status socket and against what
the link emulators really forwarded; the HTTP server's answers to bad, slow, silent and too
many clients; and the Grafana dashboard's queries against the names the daemon serves.

Everything is real: mavbond and linkemu processes, TCP and UDP sockets on 127.0.0.1."""
from __future__ import annotations

import json
import re
import socket
import time
from pathlib import Path
from typing import Dict, Tuple

import pytest
from prometheus_client.parser import text_string_to_metric_families

from helpers import (HOST, REPO, FrameMaker, free_port, recv_datagrams, rss_kib, rss_means_memory,
                     status_document, udp_client, udp_server)
from bonding_helpers import Receiver, paced_send, tlog
from synth import ardupilot_stream

DASHBOARD = REPO / "conf" / "examples" / "grafana-mavbond.json"


# --- helpers ------------------------------------------------------------------------------

def tcp_port() -> int:
    return free_port(socket.SOCK_STREAM)


def read_until_closed(s: socket.socket, timeout: float = 10.0) -> bytes:
    """Everything the server sends until it closes (bounded by `timeout`)."""
    data = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s.settimeout(max(0.05, deadline - time.monotonic()))
        try:
            chunk = s.recv(65536)
        except socket.timeout:
            break
        if not chunk:
            return data
        data += chunk
    raise AssertionError(f"the server did not close within {timeout}s; got {data[:200]!r}")


def http(port: int, raw: bytes, timeout: float = 10.0,
         head: bool = False) -> Tuple[int, Dict[str, str], bytes]:
    """Sends `raw` as is and returns (status, headers, body) of the one response."""
    with socket.create_connection((HOST, port), timeout=timeout) as s:
        s.sendall(raw)
        return parse_response(read_until_closed(s, timeout), head)


def parse_response(data: bytes, head: bool = False) -> Tuple[int, Dict[str, str], bytes]:
    """(status, headers, body); with `head`, the body must be empty whatever Content-Length
    says (the answer to HEAD)."""
    top, sep, body = data.partition(b"\r\n\r\n")
    assert sep, f"no end of headers in {data[:200]!r}"
    lines = top.decode("latin-1").split("\r\n")
    m = re.match(r"HTTP/1\.1 (\d{3}) ", lines[0])
    assert m, lines[0]
    headers = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        headers[k.strip().lower()] = v.strip()
    if head:
        assert body == b"", body[:100]
    else:
        assert int(headers["content-length"]) == len(body), (headers, len(body))
    assert headers["connection"] == "close"
    return int(m.group(1)), headers, body


def get(port: int, path: str = "/metrics") -> Tuple[int, Dict[str, str], bytes]:
    return http(port, f"GET {path} HTTP/1.1\r\nHost: {HOST}:{port}\r\n\r\n".encode())


def scrape(port: int) -> Dict[str, object]:
    """GET /metrics, parsed by prometheus_client: {"families": {name: type},
    "samples": {(sample name, sorted label items): value}}."""
    status, headers, body = get(port)
    assert status == 200, body
    assert headers["content-type"].startswith("text/plain; version=0.0.4"), headers
    families, samples = {}, {}
    for fam in text_string_to_metric_families(body.decode()):
        families[fam.name] = fam.type
        for s in fam.samples:
            key = (s.name, tuple(sorted(s.labels.items())))
            assert key not in samples, f"series {key} served twice"
            samples[key] = s.value
    return {"families": families, "samples": samples, "text": body.decode()}


def value(m: Dict[str, object], name: str, **labels) -> float:
    key = (name, tuple(sorted(labels.items())))
    samples = m["samples"]
    assert key in samples, f"{name}{labels} not served; have: " + ", ".join(
        f"{n}{dict(l)}" for n, l in samples if n == name)
    return samples[key]


def metrics_gateway(lab, tmp_path, **metrics):
    """A plain gateway (udp server `in` -> udp client `out`) with the metrics endpoint."""
    in_port, out_port, m_port = free_port(), free_port(), tcp_port()
    opts = ", ".join(f"{k}: {v}" for k, v in {"listen": f"{HOST}:{m_port}", **metrics}.items())
    g = lab.gateway([udp_server("in", in_port), udp_client("out", out_port)],
                    metrics="{" + opts + "}")
    return g, in_port, out_port, m_port


def routes(lab, in_port: int, out_port_sock: socket.socket, n: int = 20) -> int:
    """Sends n frames into the gateway; returns how many came out the other side."""
    src = lab.sock()
    frames = FrameMaker(1, 1).telemetry(n)
    for f in frames:
        src.sendto(f, (HOST, in_port))
    return len(recv_datagrams(out_port_sock, n, timeout=5.0))


# --- the figures --------------------------------------------------------------------------

def test_metrics_match_the_status_socket_and_the_links(lab, tmp_path):
    """~124 frames/s for 8 s from one vehicle over two lossy links (10% and 20% loss, seeded)
    into a ground gateway with dedup and stats. After the traffic, /metrics and the status
    socket agree on every endpoint counter and every stats/dedup figure, and the figures agree
    with the emulators: each link's frames are what its emulator forwarded, its sequence loss
    is what it dropped (less the drops at the very ends, which no sequence gap shows), and the
    delivered stream is every frame that reached the gateway on some link, exactly once."""
    la, lb, ga, gb, gcs_port = (free_port() for _ in range(5))
    m_port = tcp_port()
    status_path = tmp_path / "status.sock"
    ground = lab.gateway([udp_server("radio", ga, bond="vehicle"),
                          udp_server("lte", gb, bond="vehicle"),
                          udp_server("gcs", gcs_port)],
                         bonds=[{"name": "vehicle", "tx": "broadcast"}],
                         filters=[{"plugin": "dedup", "bonds": ["vehicle"]},
                                  {"plugin": "stats", "bonds": ["vehicle"]}],
                         name="ground", status_socket=str(status_path),
                         metrics=f"{{listen: {HOST}:{m_port}}}")
    # The same one-way delay on both links: no copy overtakes a newer sample (no stale drops).
    emu_a = lab.emu("radio", la, ga, seed=31, loss="10%", delay="10ms")
    emu_b = lab.emu("lte", lb, gb, seed=32, loss="20%", delay="10ms")
    gcs = lab.sock()
    rx = Receiver(gcs, hello_port=gcs_port)
    vehicle = lab.sock()
    sched = [(t / 1e6, f) for t, f in ardupilot_stream(8, seed=7)]
    n = len(sched)
    paced_send(sched, [(vehicle, (HOST, la)), (vehicle, (HOST, lb))])
    rx.wait_quiet(0.5)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    ca, cb = emu_a.stop(), emu_b.stop()
    da, db = emu_a.dropped(), emu_b.dropped()
    reached = [i for i in range(n) if not (i in da and i in db)]

    m = scrape(m_port)
    st = status_document(status_path)
    print(f"\n{n} frames sent; radio forwarded {ca['up']['forwarded']} (lost {len(da)}), lte "
          f"forwarded {cb['up']['forwarded']} (lost {len(db)}); {len(reached)} reached the "
          f"ground; the GCS got {len(got)}")

    # Types as the parser read them (counters are served as NAME_total).
    fams = m["families"]
    assert fams["mavbond_endpoint_rx_frames"] == "counter"
    assert fams["mavbond_stats_link_loss_ratio"] == "gauge"
    assert fams["mavbond_dedup_duplicates"] == "counter"
    assert value(m, "mavbond_build_info", version=st["version"]) == 1
    assert value(m, "mavbond_uptime_seconds") >= 8

    # Every endpoint counter the status socket shows, the same in /metrics.
    checked = 0
    for ep in st["endpoints"]:
        labels = {"endpoint": ep["name"], "kind": ep["kind"], "bond": ep["bond"]}
        for k, v in ep.items():
            if k == "last_rx_ms_ago":  # a gauge, read at another instant than the status
                age = value(m, "mavbond_endpoint_last_rx_age_seconds", **labels)
                assert v >= 0 and 0 <= age < v / 1000 + 30, (ep["name"], v, age)
            elif isinstance(v, int) and not isinstance(v, bool):
                assert value(m, f"mavbond_endpoint_{k}_total", **labels) == v, (ep["name"], k)
                checked += 1
    # for_each_counter: 17 (tx_signed too), resolve_failures, address_changes, peer_rebinds,
    # and what strangers cause: stranger_datagrams, peers_evicted, clients_refused,
    # clients_idle_closed, routes_evicted; markers_foreign
    assert checked == 3 * 26
    for ep in st["endpoints"]:
        labels = {"endpoint": ep["name"], "kind": ep["kind"], "bond": ep["bond"]}
        assert value(m, "mavbond_endpoint_open", **labels) == (1 if ep["open"] else 0)
        assert value(m, "mavbond_endpoint_state", **labels, state=ep["state"]) == 1

    filters = {f["name"]: f for f in st["filters"]}
    stats, dedup = filters["stats"]["status"], filters["dedup"]["status"]
    link_frames = {}
    for link in stats["links"]:
        # A series per endpoint: the link's peer address is on the status socket only.
        assert link["name"].startswith(link["endpoint"] + "@")
        lbl = {"filter": "stats", "link": link["endpoint"], "bond": "vehicle"}
        # The test's links send no count markers: the loss is the sequence numbers'.
        assert link["basis"] == "sequence"
        frames = value(m, "mavbond_stats_link_frames_total", **lbl)
        expected = value(m, "mavbond_stats_link_expected_frames_total", **lbl, basis="sequence")
        received = value(m, "mavbond_stats_link_received_frames_total", **lbl, basis="sequence")
        assert frames == link["frames"]
        assert expected == link["expected"] and expected - received == link["lost"]
        assert value(m, "mavbond_stats_link_loss_ratio", **lbl, basis="sequence") * 100 == \
            pytest.approx(link["loss_pct"], abs=0.0006)
        link_frames[link["endpoint"]] = (frames, expected - received)
        print(f"{link['name']}: loss_ratio "
              f"{value(m, 'mavbond_stats_link_loss_ratio', **lbl, basis='sequence'):.4f}")
    assert not any("@" in dict(labels).get("link", "") for _, labels in m["samples"]), \
        "a peer's address in a metric label"
    # ... and the emulators: frames forwarded, frames lost between the first and last one
    # that got through (one source, one sequence counter).
    for name, c, dropped in (("radio", ca, da), ("lte", cb, db)):
        frames, lost = link_frames[name]
        kept = [i for i in range(n) if i not in dropped]
        inner = sum(1 for i in dropped if kept[0] < i < kept[-1])
        assert frames == c["up"]["forwarded"], name
        assert lost == inner, (name, lost, inner, len(dropped))
        print(f"{name}: {frames:.0f} frames, {lost:.0f} lost")

    (bond,) = stats["bonds"]
    blbl = {"filter": "stats", "bond": "vehicle"}
    delivered = value(m, "mavbond_stats_bond_delivered_frames_total", **blbl)
    duplicates = value(m, "mavbond_stats_bond_duplicates_total", **blbl)
    assert delivered == bond["delivered"] == len(reached) == len(got)
    assert duplicates == bond["duplicates"]
    assert value(m, "mavbond_stats_bond_stale_total", **blbl) == bond["stale"] == 0
    d_exp = value(m, "mavbond_stats_bond_delivered_expected_frames_total", **blbl)
    d_rec = value(m, "mavbond_stats_bond_delivered_received_frames_total", **blbl)
    assert d_exp - d_rec == bond["delivered_lost"]
    d_loss = value(m, "mavbond_stats_bond_delivered_loss_ratio", **blbl)
    assert d_loss * 100 == pytest.approx(bond["delivered_loss_pct"], abs=0.0006)
    print(f"delivered {delivered:.0f}, duplicates dropped {duplicates:.0f}, delivered loss "
          f"{d_loss:.4%}")
    # Every copy is either delivered or dropped as a duplicate.
    total = sum(f for f, _ in link_frames.values())
    assert duplicates == total - delivered
    # Bonding: the delivered stream loses less than either link.
    for name, (frames, lost) in link_frames.items():
        assert d_exp - d_rec < lost, name

    dedup_dups = 0
    for link in dedup["links"]:
        v = value(m, "mavbond_dedup_duplicates_total", filter="dedup", link=link["name"].split("@")[0],
                  bond="vehicle")
        assert v == link["duplicates"]
        assert value(m, "mavbond_dedup_passed_frames_total", filter="dedup", link=link["name"].split("@")[0],
                     bond="vehicle") == link["passed"]
        dedup_dups += v
    assert dedup_dups == duplicates
    assert value(m, "mavbond_filter_dropped_total", filter="dedup", plugin="dedup") == duplicates
    # The router routed every delivered frame (and the GCS's heartbeats).
    assert value(m, "mavbond_router_frames_routed_total") >= delivered
    assert value(m, "mavbond_bond_switches_total", bond="vehicle") == 0


# --- the HTTP server ----------------------------------------------------------------------

def test_http_answers_404_405_400_431_and_head(lab, tmp_path):
    g, _, _, port = metrics_gateway(lab, tmp_path)
    status, _, body = get(port, "/")
    assert status == 404 and b"/metrics" in body
    status, headers, _ = http(port, f"POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 5"
                                    f"\r\n\r\nhello".encode())
    assert status == 405 and headers["allow"] == "GET, HEAD"
    for bad in (b"HELLO\r\n\r\n", b"GET /metrics HTTP/1.1\r\n\r\n",
                b"GET /metrics HTTP/9.9\r\nHost: x\r\n\r\n", b"\x00\xff\xfe garbage\r\n\r\n"):
        assert http(port, bad)[0] == 400, bad
    status, _, body = http(port, b"GET /metrics HTTP/1.1\r\nHost: x\r\nX-Pad: " + b"a" * 20000 +
                           b"\r\n\r\n")
    assert status == 431
    status, headers, body = http(port, b"HEAD /metrics HTTP/1.1\r\nHost: x\r\n\r\n", head=True)
    assert status == 200 and body == b"" and int(headers["content-length"]) > 1000
    assert headers["content-type"].startswith("text/plain; version=0.0.4")
    status, headers, body = get(port)
    assert status == 200 and b"mavbond_metrics_http_requests_total" in body
    assert g.alive()


def test_slow_client_byte_by_byte_is_answered(lab, tmp_path):
    """A request dribbled one byte every 20 ms (about 1 s in all) is read across many
    wakeups and answered like any other."""
    g, _, _, port = metrics_gateway(lab, tmp_path, timeout="10s")
    req = f"GET /metrics HTTP/1.1\r\nHost: {HOST}:{port}\r\n\r\n".encode()
    with socket.create_connection((HOST, port), timeout=10) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for b in req:
            s.send(bytes([b]))
            time.sleep(0.02)
        status, headers, body = parse_response(read_until_closed(s))
    assert status == 200
    fams = {f.name for f in text_string_to_metric_families(body.decode())}
    assert "mavbond_endpoint_rx_frames" in fams


def test_silent_client_is_closed_by_the_timeout_while_the_daemon_routes(lab, tmp_path):
    g, in_port, out_port, port = metrics_gateway(lab, tmp_path, timeout="1s")
    # `out` is a UDP client of out_port: the sink listens there.
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind((HOST, out_port))
    lab.socks.append(sink)
    silent = socket.create_connection((HOST, port), timeout=10)
    t0 = time.monotonic()
    # Routing goes on while the silent client holds its slot.
    assert routes(lab, in_port, sink, 20) == 20
    silent.settimeout(10)
    assert silent.recv(100) == b""  # closed by the server, with nothing sent
    waited = time.monotonic() - t0
    silent.close()
    print(f"\nsilent client closed after {waited:.2f}s (timeout 1s)")
    assert 0.9 <= waited < 8, waited
    assert routes(lab, in_port, sink, 20) == 20
    m = scrape(port)
    assert value(m, "mavbond_metrics_http_timeouts_total") == 1
    assert g.alive()


def test_connections_over_the_cap_get_503_and_the_cap_frees(lab, tmp_path):
    g, _, _, port = metrics_gateway(lab, tmp_path, timeout="30s", max_connections=3)
    held = [socket.create_connection((HOST, port), timeout=10) for _ in range(3)]
    time.sleep(0.2)  # accepted: the daemon counts them
    over = []
    for _ in range(4):
        s = socket.create_connection((HOST, port), timeout=10)
        over.append(s)
    for s in over:
        status, _, body = parse_response(read_until_closed(s, 5))
        assert status == 503 and b"too many" in body
        s.close()
    for s in held:
        s.close()
    time.sleep(0.2)  # their closes reach the daemon
    m = scrape(port)
    assert value(m, "mavbond_metrics_http_refused_total") == 4
    assert value(m, "mavbond_metrics_http_connections") == 1  # this scrape
    assert g.alive()


def test_a_flood_of_request_bytes_does_not_grow_memory(lab, tmp_path):
    """Eight clients at once each push up to 2 MiB of header without ever ending it. Each gets
    431 after max_request (8 KiB) and is cut off (after at most 64 KiB more); the daemon's
    resident memory grows by less than 1 MiB (buffering what they send would take 16 MiB).
    (How much each client got to send says little: the kernels' socket buffers take megabytes
    whatever the daemon does.)"""
    g, in_port, out_port, port = metrics_gateway(lab, tmp_path, timeout="10s")
    scrape(port)  # the first scrape's allocations are done before the baseline
    before = rss_kib(g.proc.pid)
    clients = [socket.create_connection((HOST, port), timeout=10) for _ in range(8)]
    chunk = b"GET /metrics HTTP/1.1\r\nX: " + b"a" * 65536
    pushed = [0] * len(clients)
    for i, s in enumerate(clients):
        s.settimeout(2)
        try:
            while pushed[i] < 2 << 20:
                pushed[i] += s.send(chunk)
        except (socket.timeout, ConnectionResetError, BrokenPipeError):
            pass
    answers = []
    for s in clients:
        try:
            answers.append(read_until_closed(s, 10)[:12])
        except ConnectionResetError:
            answers.append(b"reset")
        s.close()
    after = rss_kib(g.proc.pid)
    print(f"\npushed {[p >> 10 for p in pushed]} KiB; answers {answers}; RSS {before} -> "
          f"{after} KiB")
    assert all(a in (b"HTTP/1.1 431", b"reset") for a in answers), answers
    assert b"HTTP/1.1 431" in answers
    if rss_means_memory(g.proc.pid):
        assert after - before < 1024, (before, after)
    assert g.alive()
    assert get(port)[0] == 200


# --- config -------------------------------------------------------------------------------

@pytest.mark.parametrize("metrics, message", [
    ("{listen: 0.0.0.0:99999}", "metrics: 'listen': port '99999' is not in 1..65535"),
    ("{listen: example.com:9273}", "host 'example.com' is not an IPv4 address"),
    ("{port: 9273}", "metrics: unknown key 'port'"),
    ("{timeout: 1s}", "metrics: missing required key 'listen'"),
    ("{listen: 9273, max_connections: 0}", "'max_connections': '0' is not in 1..1024"),
    ("9273", "'metrics' must be a map of keys"),
])
def test_bad_metrics_config_exits_78_with_position(mavbond_bin, tmp_path, metrics, message):
    import subprocess
    path = tmp_path / "bad.yaml"
    path.write_text(f"metrics: {metrics}\nendpoints:\n  - {{name: a, type: udp, mode: server, "
                    f"address: 127.0.0.1:{free_port()}}}\n")
    r = subprocess.run([mavbond_bin, "-c", str(path), "--check-config"], capture_output=True,
                       text=True, timeout=10)
    assert r.returncode == 78, r.stderr
    assert re.match(rf"{re.escape(str(path))}:1:\d+: ", r.stderr), r.stderr
    assert message in r.stderr, r.stderr


def test_only_a_port_listens_on_loopback(lab, tmp_path):
    port = tcp_port()
    g = lab.gateway([udp_server("in", free_port())], metrics=f"{{listen: {port}}}")
    assert f"metrics at http://127.0.0.1:{port}/metrics" in g.log()
    assert get(port)[0] == 200


# --- the dashboard ------------------------------------------------------------------------

def dashboard_metric_names() -> set:
    d = json.loads(DASHBOARD.read_text())
    exprs = []
    for p in d["panels"]:
        exprs += [t["expr"] for t in p.get("targets", [])]
    for v in d["templating"]["list"]:
        q = v.get("query")
        exprs.append(q["query"] if isinstance(q, dict) else str(q))
    names = set()
    for e in exprs:
        names |= set(re.findall(r"\bmavbond_[a-zA-Z0-9_:]+", e))
    return names


def test_dashboard_uses_only_metrics_the_daemon_serves(lab, pty_pair, tmp_path):
    """The dashboard is valid JSON for Grafana 9+ with a Prometheus datasource variable, and
    every metric its queries name is served by a daemon running dedup, stats and linkswitch,
    with a metered bond member, a transmit budget and a SiK radio that reports: it has panels
    for each link's loss (by markers or by sequence), link states, standby, transmit budgets,
    the radios' signal and link silence."""
    d = json.loads(DASHBOARD.read_text())
    assert d["schemaVersion"] >= 36 and d["panels"]
    ds_vars = [v for v in d["templating"]["list"] if v["type"] == "datasource"]
    assert ds_vars and ds_vars[0]["query"] == "prometheus"
    for p in d["panels"]:
        assert p["datasource"]["uid"] == "${" + ds_vars[0]["name"] + "}", p["title"]
        assert p["targets"], p["title"]
    names = dashboard_metric_names()
    assert {"mavbond_stats_link_expected_frames_total",
            "mavbond_stats_bond_delivered_expected_frames_total", "mavbond_dedup_duplicates_total",
            "mavbond_bond_active_link", "mavbond_endpoint_state", "mavbond_standby_active",
            "mavbond_endpoint_tx_rate_bytes", "mavbond_endpoint_tx_class_thinned_total",
            "mavbond_endpoint_radio_rssi", "mavbond_endpoint_last_rx_age_seconds"} <= names
    exprs = [t["expr"] for p in d["panels"] for t in p["targets"]]
    assert any('basis="markers"' in e and 'basis="sequence"' in e for e in exprs), \
        "the loss panel reads each link's loss by markers where there are, else by sequence"

    ports = {k: free_port() for k in ("a1", "a2", "b1", "b2", "m1", "m2", "gcs")}
    m_port = tcp_port()
    radio = pty_pair()
    g = lab.gateway([udp_server("a1", ports["a1"], bond="bonded"),
                     udp_server("a2", ports["a2"], bond="bonded"),
                     udp_server("b1", ports["b1"], bond="backup"),
                     udp_server("b2", ports["b2"], bond="backup"),
                     udp_server("m1", ports["m1"], bond="paid"),
                     udp_server("m2", ports["m2"], bond="paid", cost="metered"),
                     udp_server("gcs", ports["gcs"], tx_rate="1MB/s"),
                     {"name": "r1", "type": "uart", "device": radio.path, "baud": 57600,
                      "radio_status": "sik", "bond": "radio"}],
                    bonds=[{"name": "bonded", "tx": "broadcast"}, {"name": "backup", "tx": "active"},
                           {"name": "paid"}, {"name": "radio"}],
                    filters=[{"plugin": "dedup", "bonds": ["bonded"]},
                             {"plugin": "linkswitch", "bonds": ["backup"]},
                             {"plugin": "stats"}],
                    metrics=f"{{listen: {HOST}:{m_port}}}")
    src = lab.sock()
    frames = [f for _, f in ardupilot_stream(1, seed=3)]
    for f in frames:
        for k in ("a1", "a2", "b1", "b2", "m1", "m2"):
            src.sendto(f, (HOST, ports[k]))
    g.wait_log(r"\[uart:r1\] .* open at 57600 baud")
    sik = FrameMaker(51, 68, v1=True)
    radio.write_all(sik.pack(sik.mod.MAVLink_radio_status_message(150, 140, 95, 40, 35, 3, 1)))
    deadline = time.monotonic() + 10
    while True:
        m = scrape(m_port)
        served = {name for name, _ in m["samples"]}
        if names <= served or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert names <= served, f"the dashboard queries metrics nobody serves: {names - served}"
    assert g.alive()
