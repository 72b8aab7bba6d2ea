"""Security notes made checks: the status socket serves only root, mavbond's own user and the
socket's group (SO_PEERCRED), even when its file mode is opened by mistake; it is not created
in a directory others may write without the sticky bit, nor over a file that is not a socket;
a listener on 127.0.0.1 is bound there and nowhere else. Needs root (tests run as root):
children drop to uid/gid 65534 to play the other users."""
from __future__ import annotations

import json
import re
import os
import shutil
import socket
import stat
import tempfile
from pathlib import Path

import pytest

from helpers import HOST, Daemon, free_port, make_config, run_as, tcp_server, udp_server

NOBODY = 65534
OTHER_GID = 65533

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to play other users")


def fetch(path: str) -> bytes:
    """What the status socket sends to this process; raises OSError if it cannot connect."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(3)
        s.connect(path)
        out = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                return out
            out += chunk


def fetch_as(path: str, uid: int, gid: int, groups=()) -> str:
    """fetch() in a forked child running as uid/gid: 'doc:<n bytes>', 'empty', or 'error:<errno
    name>'."""
    def work() -> str:
        try:
            data = fetch(path)
            return f"doc:{len(data)}" if data else "empty"
        except OSError as e:
            return f"error:{e.__class__.__name__}"
    return run_as(uid, gid, work, groups)()


@pytest.fixture
def sock_dir():
    """A directory other users may enter (pytest's tmp_path is 0700 under a 0700 parent)."""
    d = Path(tempfile.mkdtemp(prefix="mavbond-sec-", dir="/tmp"))
    os.chmod(d, 0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


def start(mavbond_bin, workdir: Path, sock: Path) -> Daemon:
    cfg = make_config([udp_server("gcs", free_port())], status_socket=str(sock))
    return Daemon(mavbond_bin, workdir, cfg).start()


def test_status_socket_serves_only_root_own_user_and_group(mavbond_bin, tmp_path, sock_dir):
    sock = sock_dir / "status.sock"
    d = start(mavbond_bin, tmp_path, sock)
    d.wait_log("status socket at")
    mode = stat.S_IMODE(os.stat(sock).st_mode)
    doc = json.loads(fetch(str(sock)))
    results = {"root": f"doc:{len(json.dumps(doc))}"}
    # 0660 root:root: another user cannot even connect (the file mode).
    results["nobody, 0660"] = fetch_as(str(sock), NOBODY, NOBODY)
    # The mode opened by mistake: the kernel lets them connect, the daemon refuses them.
    os.chmod(sock, 0o666)
    results["nobody, 0666"] = fetch_as(str(sock), NOBODY, NOBODY)
    refused_log = d.wait_log(rf"status socket: refusing pid \d+ uid {NOBODY} gid {NOBODY}")
    # The socket's group may read it: as primary group, or as a supplementary one.
    os.chmod(sock, 0o660)
    os.chown(sock, 0, NOBODY)
    results["group, primary"] = fetch_as(str(sock), NOBODY, NOBODY)
    results["group, supplementary"] = fetch_as(str(sock), NOBODY, OTHER_GID, groups=[NOBODY])
    os.chmod(sock, 0o666)
    results["other group, 0666"] = fetch_as(str(sock), NOBODY, OTHER_GID)
    after = json.loads(fetch(str(sock)))
    print(f"\nsocket mode {mode:04o}; " + "; ".join(f"{k}: {v}" for k, v in results.items()) +
          f"; status_refused {doc['status_refused']} -> {after['status_refused']}")
    assert mode == 0o660
    assert doc["status_refused"] == 0 and doc["endpoints"][0]["name"] == "gcs"
    assert "sig_replay" in doc["endpoints"][0], "the signing counters are in the document"
    assert results["nobody, 0660"] == "error:PermissionError"
    assert results["nobody, 0666"] == "empty"
    assert results["group, primary"].startswith("doc:")
    assert results["group, supplementary"].startswith("doc:")
    assert results["other group, 0666"] == "empty"
    assert after["status_refused"] == 2
    assert "refusing pid" in refused_log
    assert d.stop() == 0


def test_status_socket_refuses_unsafe_places(mavbond_bin, tmp_path, sock_dir):
    # A directory anyone may write, no sticky bit: refused, the daemon routes on without it.
    open_dir = sock_dir / "open"
    open_dir.mkdir()
    os.chmod(open_dir, 0o777)
    d1 = start(mavbond_bin, tmp_path, open_dir / "status.sock")
    log1 = d1.wait_log("refusing to create status socket")
    created_in_open_dir = (open_dir / "status.sock").exists()
    assert d1.stop() == 0
    # The same with the sticky bit (as /tmp): accepted.
    os.chmod(open_dir, 0o1777)
    d2 = start(mavbond_bin, tmp_path, open_dir / "status.sock")
    d2.wait_log("status socket at")
    sticky_ok = (open_dir / "status.sock").is_socket()
    assert d2.stop() == 0
    # A regular file and a symlink where the socket should be: left alone.
    regular = sock_dir / "file.sock"
    regular.write_text("precious\n")
    d3 = start(mavbond_bin, tmp_path, regular)
    log3 = d3.wait_log("exists and is not a socket")
    assert d3.stop() == 0
    target = sock_dir / "target"
    target.write_text("also precious\n")
    link = sock_dir / "link.sock"
    link.symlink_to(target)
    d4 = start(mavbond_bin, tmp_path, link)
    d4.wait_log("exists and is not a socket")
    assert d4.stop() == 0
    line = [l for l in log1.splitlines() if "refusing to create" in l][0]
    print(f"\n{line.strip()}\nsticky dir: socket created {sticky_ok}; regular file kept "
          f"{regular.read_text()!r}; symlink kept {link.is_symlink()}")
    assert "mode 0777" in line and "no sticky bit" in line
    assert not created_in_open_dir
    assert sticky_ok
    assert regular.read_text() == "precious\n" and "is not a socket" in log3
    assert link.is_symlink() and target.read_text() == "also precious\n"


def bound_addresses(table: str, port: int):
    """Local addresses (dotted quad) of the sockets in /proc/net/<table> on `port`."""
    out = []
    with open(f"/proc/net/{table}") as f:
        next(f)
        for line in f:
            local = line.split()[1]
            addr_hex, port_hex = local.split(":")
            if int(port_hex, 16) == port:
                out.append(socket.inet_ntoa(bytes.fromhex(addr_hex)[::-1]))
    return out


def test_loopback_listeners_bind_loopback_only(start_daemon):
    udp_port, tcp_port = free_port(), free_port(socket.SOCK_STREAM)
    d = start_daemon([udp_server("gcs", udp_port), tcp_server("api", tcp_port)])
    udp, tcp = bound_addresses("udp", udp_port), bound_addresses("tcp", tcp_port)
    print(f"\nudp {udp_port} bound on {udp}; tcp {tcp_port} bound on {tcp}")
    assert udp == [HOST], "one UDP socket, on 127.0.0.1 only (not 0.0.0.0)"
    assert tcp == [HOST]
    assert d.stop() == 0


# The shipped configs' listeners off loopback, each needed and explained in its comment: a GCS
# on another machine, the vehicle's LTE modem on the internet. Anything else binds 127.0.0.1.
PUBLIC_ON_PURPOSE = {
    "conf/mavbond.yaml": {"gcs"},
    "conf/examples/ground-side.yaml": {"lte"},
    "conf/examples/air-side.yaml": set(),
}


@pytest.mark.parametrize("rel", sorted(PUBLIC_ON_PURPOSE))
def test_shipped_configs_listen_publicly_only_where_needed(rel):
    from helpers import REPO
    text = (REPO / rel).read_text()
    servers, names, name, mode = {}, [], None, None
    for line in text.splitlines():
        code = line.split("#", 1)[0]
        if m := re.match(r"\s*-\s*name:\s*(\S+)", code):
            name, mode = m.group(1), None
            names.append(name)
        elif m := re.match(r"\s*mode:\s*(\S+)", code):
            mode = m.group(1)
        elif (m := re.match(r"\s*address:\s*(\S+):\d+", code)) and mode == "server":
            servers[name] = m.group(1)
    public = {n for n, host in servers.items() if host != HOST}
    print(f"\n{rel}: endpoints {names}, servers {servers}")
    assert len(names) >= 2, "the parser found the endpoints"
    assert public == PUBLIC_ON_PURPOSE[rel]
    for n in public:  # the reason is written next to the address
        block = text[text.index(f"name: {n}"):]
        address_line = next(l for l in block.splitlines() if "address:" in l)
        assert "#" in address_line, f"{n}: no comment says why it listens on {servers[n]}"
