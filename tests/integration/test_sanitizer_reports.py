"""The check behind the sanitizer build (scripts/test's build-asan): a Daemon whose log holds a
sanitizer report fails its test, also when the report only comes at exit (LeakSanitizer, which
needs the SIGTERM that Daemon.kill() now sends first). A stand-in process plays the daemon so
that the check is tested in every build, sanitized or not."""
from __future__ import annotations

import stat
import textwrap

import pytest

from helpers import Daemon, make_config, udp_server

LEAK_REPORT = "==4242==ERROR: LeakSanitizer: detected memory leaks"
UBSAN_REPORT = "../src/x.cpp:1:2: runtime error: signed integer overflow"


def stand_in(tmp_path, at_start: str = "", at_exit: str = "") -> str:
    """A script that logs like mavbond ('running with'), prints `at_exit` on SIGTERM and
    exits 0, as a sanitized daemon does when LeakSanitizer reports."""
    path = tmp_path / "fake-mavbond"
    path.write_text(textwrap.dedent(f"""\
        #!/bin/sh
        trap 'echo "{at_exit}"; exit 0' TERM
        echo "{at_start}"
        echo "mavbond running with 1 endpoint"
        i=0
        while [ $i -lt 300 ]; do sleep 0.1; i=$((i + 1)); done
        """))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return str(path)


def make(tmp_path, **kw) -> Daemon:
    d = Daemon(stand_in(tmp_path, **kw), tmp_path, make_config([udp_server("a", 1)]))
    Daemon.created.remove(d)   # checked here, not by conftest's autouse fixture
    return d.start()


def test_report_at_exit_fails_stop(tmp_path):
    d = make(tmp_path, at_exit=LEAK_REPORT)
    with pytest.raises(AssertionError, match="LeakSanitizer: detected memory leaks"):
        d.stop()


def test_report_while_running_fails_stop(tmp_path):
    d = make(tmp_path, at_start=UBSAN_REPORT)
    with pytest.raises(AssertionError, match="runtime error: signed integer overflow"):
        d.stop()


def test_kill_sends_sigterm_first_so_leaks_are_reported(tmp_path):
    d = make(tmp_path, at_exit=LEAK_REPORT)
    d.kill()
    assert d.proc.returncode == 0, "ended by SIGKILL, not by its SIGTERM handler"
    with pytest.raises(AssertionError, match="LeakSanitizer"):
        d.check_sanitizers()


def test_clean_log_passes(tmp_path):
    d = make(tmp_path, at_exit="stats endpoint=a kind=udp-server rx_frames=0")
    assert d.stop() == 0
