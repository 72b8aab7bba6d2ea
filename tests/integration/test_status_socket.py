"""The status socket belongs to the daemon that made it: a second instance with the same
status_socket refuses to start, naming the one that answers there, and leaves its socket
alone; a file left by a daemon that was killed is replaced; a daemon removes at exit only
the socket it made (issue 21, item 7)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

from helpers import Daemon, free_port, make_config, status_document, udp_server

EX_OSERR = 71


def daemon(mavbond_bin, tmp_path: Path, name: str, sock: Path, endpoint: str) -> Daemon:
    cfg = make_config([udp_server(endpoint, free_port())], status_socket=str(sock))
    return Daemon(mavbond_bin, tmp_path, cfg, name=name)


def test_a_second_instance_leaves_the_running_daemons_socket_alone(mavbond_bin, tmp_path):
    sock = tmp_path / "status.sock"
    first = daemon(mavbond_bin, tmp_path, "first", sock, "gcs1").start()
    first.wait_log("status socket at")
    inode = sock.stat().st_ino
    second = daemon(mavbond_bin, tmp_path, "second", sock, "gcs2")
    r = subprocess.run([mavbond_bin, "-c", str(second.config_path)], capture_output=True,
                       text=True, timeout=10)
    print(f"\nsecond instance: exit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == EX_OSERR
    assert f"status socket {sock}: a running process (pid {first.proc.pid}) answers there" in r.stderr
    assert "stop it first, or give this one a status_socket of its own" in r.stderr
    # The first daemon's socket is the same file, and still reaches it.
    assert sock.stat().st_ino == inode
    assert status_document(sock)["endpoints"][0]["name"] == "gcs1"
    assert first.stop() == 0
    assert not sock.exists(), "a daemon removes the socket it made"


def test_a_killed_daemons_socket_file_is_replaced(mavbond_bin, tmp_path):
    sock = tmp_path / "status.sock"
    first = daemon(mavbond_bin, tmp_path, "first", sock, "gcs1").start()
    first.wait_log("status socket at")
    first.proc.kill()  # SIGKILL: the file stays, nobody answers on it
    first.proc.wait()
    assert sock.is_socket()
    second = daemon(mavbond_bin, tmp_path, "second", sock, "gcs2").start()
    second.wait_log("status socket at")
    assert status_document(sock)["endpoints"][0]["name"] == "gcs2"
    assert second.stop() == 0


def test_a_daemon_removes_only_the_socket_it_made(mavbond_bin, tmp_path):
    # The first daemon's file is taken away (by hand) and a second daemon makes its own at the
    # same path: the first one's exit must not delete the second one's socket.
    sock = tmp_path / "status.sock"
    first = daemon(mavbond_bin, tmp_path, "first", sock, "gcs1").start()
    first.wait_log("status socket at")
    os.unlink(sock)
    second = daemon(mavbond_bin, tmp_path, "second", sock, "gcs2").start()
    second.wait_log("status socket at")
    assert first.stop() == 0
    assert sock.is_socket(), "the first daemon deleted the second one's socket at exit"
    assert status_document(sock)["endpoints"][0]["name"] == "gcs2"
    assert second.stop() == 0
    assert not sock.exists()
