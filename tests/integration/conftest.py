"""Fixtures for the integration tests: the mavbond binary, a daemon factory that always kills
what it started, pty pairs, and the shared tlog directory."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from helpers import REPO, Daemon, Pty, make_config


@pytest.fixture(autouse=True)
def no_sanitizer_reports():
    """After every test (and the fixtures that stop its daemons): each mavbond it created is
    ended with SIGTERM, so LeakSanitizer runs, and a sanitizer report in any of their logs
    fails the test. Without a sanitizer build there is never one."""
    Daemon.created.clear()
    yield
    daemons = list(Daemon.created)
    Daemon.created.clear()
    reports = []
    for d in daemons:
        d.kill()
        try:
            d.check_sanitizers()
        except AssertionError as e:
            reports.append(str(e))
    if reports:
        pytest.fail("\n\n".join(reports), pytrace=False)


@pytest.fixture(scope="session")
def mavbond_bin() -> str:
    path = os.environ.get("MAVBOND_BIN", str(REPO / "build" / "src" / "mavbond"))
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        pytest.fail(f"mavbond binary not found at {path}: build it (meson setup build && ninja -C "
                    f"build) or point MAVBOND_BIN at it", pytrace=False)
    return path


@pytest.fixture(scope="session")
def plugin_dir(mavbond_bin) -> str:
    """The build's plugin directory (<build>/plugins), for --plugin-dir."""
    from bonding_helpers import plugin_dir_for
    return plugin_dir_for(mavbond_bin)


@pytest.fixture
def start_daemon(mavbond_bin, tmp_path):
    """start_daemon(endpoints, name="mavbond", wait_for=..., **top_level_keys) -> Daemon.
    Every daemon started is killed when the test ends, whatever happened."""
    started = []

    def start(endpoints, name="mavbond", wait_for="running with", **top):
        d = Daemon(mavbond_bin, tmp_path, make_config(endpoints, **top), name=name)
        started.append(d)
        return d.start(wait_for=wait_for)

    yield start
    for d in started:
        d.kill()


@pytest.fixture
def pty_pair():
    """pty_pair() -> Pty; every master is closed when the test ends."""
    made = []

    def make():
        p = Pty()
        made.append(p)
        return p

    yield make
    for p in made:
        p.close()


@pytest.fixture(scope="session")
def tlog_dir() -> Path:
    d = Path(os.environ.get("MAVBOND_TLOG_DIR", REPO.parent / "shared" / "data" / "tlogs"))
    if not d.is_dir() or not any(d.iterdir()):
        pytest.skip(f"no recorded telemetry in {d} (set MAVBOND_TLOG_DIR to a directory of "
                    f".tlog/.mavlink files)")
    return d


def tlog_files():
    d = Path(os.environ.get("MAVBOND_TLOG_DIR", REPO.parent / "shared" / "data" / "tlogs"))
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if p.suffix in (".tlog", ".mavlink"))


@pytest.fixture
def lab(mavbond_bin, tmp_path, plugin_dir):
    """Factories for gateways and link emulators; everything started is stopped at the end."""
    from bonding_helpers import Emu, EmuGroup, Gateway, Stall, udp_sock

    class Lab:
        def __init__(self):
            self.gateways, self.emus, self.socks, self.stalls = [], [], [], []
            self.workdir = tmp_path

        def gateway(self, endpoints, bonds=(), filters=(), name="mavbond", **top):
            g = Gateway(mavbond_bin, tmp_path, endpoints, bonds, filters, name=name,
                        plugin_dir=plugin_dir, **top)
            self.gateways.append(g)
            return g.start()

        def emu(self, name, listen_port, forward_port, seed, **opts):
            e = Emu(tmp_path, name, listen_port, forward_port, seed=seed, **opts)
            self.emus.append(e)
            return e.start()

        def emu_group(self, links, name="group", duration=None, log_sends=False):
            """One linkemu process for several links (EmuGroup); links: dicts with name,
            listen_port, forward_ports (one or a list: a tee), seed and link options."""
            e = EmuGroup(tmp_path, name, links, duration=duration, log_sends=log_sends)
            self.emus.append(e)
            return e.start()

        def stall(self, process, duration, **schedule):
            """Stall(pid, duration=..., every=(2.0, 2.5), length=0.15, long_stalls=(),
            seed=1) on a gateway, a Popen or a pid; started, and stopped at teardown."""
            proc = getattr(process, "proc", process)
            pid = getattr(proc, "pid", proc)
            s = Stall(pid, duration=duration, **schedule)
            self.stalls.append(s)
            return s.start()

        def sock(self, port=0):
            s = udp_sock(port)
            self.socks.append(s)
            return s

    lab = Lab()
    yield lab
    for s in lab.stalls:   # before the gateways go: none is left frozen
        s.stop()
    for g in lab.gateways:
        g.kill()
    for e in lab.emus:
        e.kill()
    for s in lab.socks:
        s.close()
