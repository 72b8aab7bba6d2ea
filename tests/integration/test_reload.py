"""Live reload (SIGHUP) against the real daemon: what did not change keeps running without a
lost frame, what changed restarts, and a bad new config is refused with its error while the
old one keeps running."""
from __future__ import annotations

import signal
import threading
import time

import pytest

from bonding_helpers import Gateway, bond_config
from helpers import (FrameMaker, drain, free_port, recv_datagrams, udp_client, udp_server,
                     udp_socket)


class Sender(threading.Thread):
    """Sends `frames` to `port` at about `rate` frames/s, one per datagram."""

    def __init__(self, port: int, frames, rate: float = 1000.0):
        super().__init__(daemon=True)
        self.port, self.frames, self.rate = port, frames, rate
        self.sock = udp_socket()

    def run(self):
        start = time.monotonic()
        for i, f in enumerate(self.frames):
            self.sock.sendto(f, ("127.0.0.1", self.port))
            delay = start + (i + 1) / self.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)


@pytest.fixture
def gateway(mavbond_bin, plugin_dir, tmp_path):
    """gateway(endpoints, filters) -> a started Gateway, killed when the test ends."""
    started = []

    def start(endpoints, filters=(), bonds=()):
        gw = Gateway(mavbond_bin, tmp_path, endpoints, bonds, filters, plugin_dir=plugin_dir)
        started.append(gw)
        return gw.start()

    yield start
    for gw in started:
        gw.kill()


def distinct_frames(n: int):
    """n frames whose bytes all differ (ATTITUDE with a running timestamp)."""
    fm = FrameMaker(1, 1)
    return [fm.attitude(1000 + i) for i in range(n)]


def reload(gw: Gateway, endpoints, filters=(), count: int = 1, timeout: float = 5.0,
           bonds=(), comment: str = "") -> str:
    """Rewrites the gateway's config, sends SIGHUP and waits for the count-th reload line."""
    gw.config_path.write_text(comment + bond_config(endpoints, bonds, filters))
    gw.endpoint_names = [e["name"] for e in endpoints]
    gw.proc.send_signal(signal.SIGHUP)
    return gw.wait_log(r"reloaded: |reload refused", timeout=timeout, count=count)


def test_reload_under_load_loses_nothing(gateway):
    """3,000 frames at 1,000/s through src -> sink while the config is reloaded four times:
    an endpoint added, the log level changed, the filters changed (restarted), the endpoint
    removed. The sink gets every frame once, in order; the added endpoint gets frames while
    it exists."""
    src_port, sink_port, extra_port = free_port(), free_port(), free_port()
    sink, extra = udp_socket(sink_port), udp_socket(extra_port)
    base = [udp_server("src", src_port), udp_client("sink", sink_port)]
    stats = [{"plugin": "stats"}]
    gw = gateway(base, stats)
    frames = distinct_frames(3000)
    sender = Sender(src_port, frames)
    received = []
    stop = threading.Event()

    def receive():
        while not stop.is_set() or len(received) < len(frames):
            got = recv_datagrams(sink, None, timeout=0.5, quiet=0.5)
            received.extend(got)
            if stop.is_set() and not got:
                break

    reader = threading.Thread(target=receive, daemon=True)
    reader.start()
    sender.start()
    time.sleep(0.4)
    with_extra = base + [udp_client("extra", extra_port)]
    log = reload(gw, with_extra, stats, count=1)
    assert "reloaded: 2 endpoints kept, 0 stopped, 1 started; filters kept" in log
    time.sleep(0.4)
    log = reload(gw, with_extra, stats + [{"plugin": "dedup"}], count=2)
    assert "reloaded: 3 endpoints kept, 0 stopped, 0 started; filters restarted" in log
    time.sleep(0.4)
    log = reload(gw, base, stats + [{"plugin": "dedup"}], count=3)
    assert "reloaded: 2 endpoints kept, 1 stopped, 0 started; filters kept" in log
    sender.join(timeout=30)
    assert not sender.is_alive()
    stop.set()
    reader.join(timeout=30)
    extra_got = recv_datagrams(extra, None, timeout=2)

    assert len(received) == len(frames), \
        f"sink got {len(received)} of {len(frames)} frames across three reloads"
    assert received == frames, "frames reordered or altered across reloads"
    assert 0 < len(extra_got) < len(frames), \
        f"the endpoint added then removed got {len(extra_got)} frames"
    assert all(f in set(frames) for f in extra_got)
    assert gw.alive()
    assert gw.stop() == 0


def test_bad_config_is_refused_and_the_old_one_keeps_running(gateway):
    """A YAML error and an unknown plugin option are refused with file:line:column; the
    running endpoints go on routing, and a later good config still applies."""
    src_port, sink_port = free_port(), free_port()
    sink = udp_socket(sink_port)
    base = [udp_server("src", src_port), udp_client("sink", sink_port)]
    gw = gateway(base)
    tx = udp_socket()

    def routes(n: int) -> bool:
        frames = distinct_frames(n)
        for f in frames:
            tx.sendto(f, ("127.0.0.1", src_port))
        return recv_datagrams(sink, n, timeout=5) == frames

    assert routes(20)
    # A syntax error: an unclosed flow mapping.
    gw.config_path.write_text("endpoints:\n  - {name: src, type: udp\n")
    gw.proc.send_signal(signal.SIGHUP)
    log = gw.wait_log(r"reload refused", count=1)
    assert f"reload refused, the running configuration stays: {gw.config_path}:" in log
    assert routes(20)

    # A valid YAML whose filter option the plugin does not know: refused at the filter.
    log = reload(gw, base, [{"plugin": "dedup", "no_such_option": 1}], count=2)
    refused = [ln for ln in log.splitlines() if "reload refused" in ln][-1]
    assert f"{gw.config_path}:" in refused and "no_such_option" in refused, refused
    assert routes(20)

    # A good config after that applies.
    moved_port = free_port()
    moved = udp_socket(moved_port)
    log = reload(gw, [udp_server("src", src_port), udp_client("sink", moved_port)], count=3)
    assert "reloaded: 1 endpoint kept, 1 stopped, 1 started; filters kept" in log
    frames = distinct_frames(10)
    for f in frames:
        tx.sendto(f, ("127.0.0.1", src_port))
    assert recv_datagrams(moved, 10, timeout=5) == frames
    assert drain(sink) == 0, "the replaced endpoint still sent"
    assert gw.stop() == 0


def test_endpoint_that_cannot_start_is_reported(gateway):
    """A new endpoint whose port is taken is logged and left out; the rest of the new config
    applies and the kept endpoints keep routing."""
    src_port, sink_port = free_port(), free_port()
    sink = udp_socket(sink_port)
    taken = udp_socket(free_port())
    base = [udp_server("src", src_port), udp_client("sink", sink_port)]
    gw = gateway(base)
    busy = udp_server("busy", taken.getsockname()[1])
    log = reload(gw, base + [busy], count=1)
    assert "reload: endpoint 'busy':" in log
    assert "reloaded: 2 endpoints kept, 0 stopped, 0 started, 1 failed; filters kept" in log
    tx = udp_socket()
    frames = distinct_frames(20)
    for f in frames:
        tx.sendto(f, ("127.0.0.1", src_port))
    assert recv_datagrams(sink, 20, timeout=5) == frames
    assert gw.stop() == 0


def test_unchanged_filters_keep_their_state(gateway):
    """A bond of two links with dedup: a frame comes on link A, the config is reloaded with
    only its layout changed (a comment, so every line moves), then its copy comes on link B.
    dedup kept its window across the reload, so the copy is dropped; after a reload that does
    change the bond (the order of its links), the filters restart and the same copy passes
    again."""
    a_port, b_port, gcs_port = free_port(), free_port(), free_port()
    gcs = udp_socket(gcs_port)
    eps = [udp_server("a", a_port, bond="air"), udp_server("b", b_port, bond="air"),
           udp_client("gcs", gcs_port)]
    bonds = [{"name": "air", "tx": "broadcast"}]
    filters = [{"plugin": "dedup", "bonds": ["air"], "window": "30s"}]
    gw = gateway(eps, filters, bonds)
    link_a, link_b = udp_socket(), udp_socket()
    frame = distinct_frames(1)[0]
    link_a.sendto(frame, ("127.0.0.1", a_port))
    assert recv_datagrams(gcs, 1, timeout=5) == [frame]

    log = reload(gw, eps, filters, bonds=bonds, comment="# moved down a line\n")
    assert "reloaded: 3 endpoints kept, 0 stopped, 0 started; filters kept" in log
    link_b.sendto(frame, ("127.0.0.1", b_port))
    assert recv_datagrams(gcs, None, timeout=1.5) == [], "dedup forgot its window on reload"

    # The bond's links in another order (its links' priority): the filters restart. (`tx:
    # active` did here once; without a linkswitch filter that is now a config error.)
    log = reload(gw, [eps[1], eps[0], eps[2]], filters, bonds=bonds, count=2)
    assert "reloaded: 3 endpoints kept, 0 stopped, 0 started; filters restarted" in log
    link_b.sendto(frame, ("127.0.0.1", b_port))
    assert recv_datagrams(gcs, 1, timeout=5) == [frame], "a restarted dedup starts empty"
    status = gw.stats()
    assert status["a"]["rx_frames"] == 1 and status["b"]["rx_frames"] == 2
    assert gw.stop() == 0
