"""Every kind of config error, against the real binary: --check-config and a normal start both
exit with exactly 78 (EX_CONFIG, not a signal), and stderr starts with the exact
"file:line:column: " of the fault, then says what is wrong. The cases cover every key the
loader knows (src/config/config.cpp) and the options of the three plugins.

A case is (id, YAML text, words the message must contain). The text marks the fault with »:
the marker is removed before the file is written, and its place is the line and column the
message must name. (tests/unit/config checks the loader's messages in-process; this checks
what an operator sees from the daemon.)"""
from __future__ import annotations

import subprocess

import pytest

HERE = "»"
UDP = "{name: a, type: udp, mode: server, address: 127.0.0.1:14550}"
UDP_B = "{name: b, type: udp, mode: server, address: 127.0.0.1:14551}"


def doc(*endpoints: str, top: str = "", tail: str = "") -> str:
    """A config: top-level lines, the endpoints (flow maps), then more sections."""
    return top + "endpoints:\n" + "".join(f"  - {e}\n" for e in endpoints) + tail


def ep(**kw) -> str:
    """A flow-map endpoint: a UDP server named a unless overridden; None removes a key."""
    base = {"name": "a", "type": "udp", "mode": "server", "address": "127.0.0.1:14550"}
    base.update(kw)
    return "{" + ", ".join(f"{k}: {v}" for k, v in base.items() if v is not None) + "}"


UART = dict(type="uart", mode=None, address=None, device="/dev/ttyNONE")
TCP_CLIENT = dict(type="tcp", mode="client")
BONDED = doc(ep(name="r", bond="v"), ep(name="l", address="127.0.0.1:14551", bond="v"),
             tail="bonds:\n  - {name: v}\n")


def with_filter(entry: str) -> str:
    return BONDED + "filters:\n  - " + entry + "\n"


CASES = [
    # --- the document ----------------------------------------------------------------------
    ("empty-file", f"{HERE}", ["empty"]),
    ("top-is-a-list", f"{HERE}- a\n- b\n", ["top level must be a map"]),
    ("yaml-syntax", f"log_level: info\nendpoints: [{{name: a\n{HERE}", []),
    ("second-document", doc(UDP) + f"---\n{HERE}log_level: info\n", ["only one YAML document"]),
    ("unknown-top-key", doc(UDP, top=f"{HERE}colour: red\n"), ["unknown key 'colour'"]),
    ("duplicate-top-key", doc(UDP, top=f"log_level: info\n{HERE}log_level: debug\n"),
     ["duplicate key 'log_level'"]),
    ("non-scalar-key", doc(UDP, top=f"{HERE}[a, b]: c\n"), ["plain word"]),
    # --- top-level keys ----------------------------------------------------------------------
    ("log_level-invalid", doc(UDP, top=f"log_level: {HERE}loud\n"), ["log_level", "loud"]),
    ("log_level-empty", doc(UDP, top=f"{HERE}log_level:\n"), ["'log_level' needs a value"]),
    ("log_level-list", doc(UDP, top=f"log_level: {HERE}[info, debug]\n"),
     ["single value", "sequence"]),
    ("unknown_messages-invalid", doc(UDP, top=f"unknown_messages: {HERE}keep\n"),
     ["unknown_messages", "keep", "forward, drop"]),
    ("route_timeout-no-unit", doc(UDP, top=f"route_timeout: {HERE}30\n"), ["needs a unit"]),
    ("route_timeout-word", doc(UDP, top=f"route_timeout: {HERE}soon\n"), ["invalid duration"]),
    ("route_timeout-negative", doc(UDP, top=f"route_timeout: {HERE}-5s\n"), ["invalid duration"]),
    ("report_interval-zero", doc(UDP, top=f"report_interval: {HERE}0s\n"), ["greater than 0"]),
    ("report_interval-subnano", doc(UDP, top=f"report_interval: {HERE}1.5ns\n"),
     ["invalid duration"]),
    ("report_interval-map", doc(UDP, top=f"report_interval: {HERE}{{a: 1}}\n"), ["single value"]),
    ("plugin_dir-map", doc(UDP, top=f"plugin_dir: {HERE}{{a: b}}\n"),
     ["plugin_dir", "single value"]),
    ("status_socket-list", doc(UDP, top=f"status_socket: {HERE}[a, b]\n"),
     ["status_socket", "single value"]),
    ("endpoints-missing", f"{HERE}log_level: info\n", ["missing required key 'endpoints'"]),
    ("endpoints-empty", f"endpoints: {HERE}[]\n", ["non-empty sequence"]),
    ("endpoints-scalar", f"endpoints: {HERE}udp\n", ["non-empty sequence"]),
    # --- endpoints: shape and names ----------------------------------------------------------
    ("endpoint-scalar", f"endpoints:\n  - {HERE}udp\n", ["endpoint #1", "map"]),
    ("endpoint-no-name", doc(UDP, f"{HERE}" + ep(name=None)), ["endpoint #2", "'name'"]),
    ("endpoint-name-empty", doc(ep(name=f'{HERE}""')), ["'name' must not be empty"]),
    ("endpoint-name-chars", doc(ep(name=f"{HERE}a/b")), ["invalid name 'a/b'"]),
    ("endpoint-name-duplicate", doc(UDP, ep(name=f"{HERE}a", address="127.0.0.1:1")),
     ["duplicate endpoint name 'a'"]),
    ("endpoint-unknown-key", doc(UDP[:-1] + f", {HERE}colour: red}}"), ["unknown key 'colour'"]),
    ("endpoint-duplicate-key", doc(UDP[:-1] + f", {HERE}mode: client}}"), ["duplicate key 'mode'"]),
    ("type-missing", doc(f"{HERE}" + ep(type=None)), ["missing required key 'type'"]),
    ("type-invalid", doc(ep(type=f"{HERE}serial")), ["invalid type 'serial'", "udp, tcp, uart"]),
    ("mode-missing", doc(f"{HERE}" + ep(mode=None)), ["missing required key 'mode'"]),
    ("mode-invalid", doc(ep(mode=f"{HERE}listen")), ["invalid mode 'listen'"]),
    # --- address ----------------------------------------------------------------------------
    ("address-missing", doc(f"{HERE}" + ep(address=None)), ["missing required key 'address'"]),
    ("address-no-port", doc(ep(address=f"{HERE}127.0.0.1")), ["needs host:port"]),
    ("address-hostname", doc(ep(address=f"{HERE}example.com:14550")), ["not an IPv4 address"]),
    ("address-port-zero", doc(ep(address=f"{HERE}127.0.0.1:0")), ["port '0'"]),
    ("address-port-big", doc(ep(address=f"{HERE}127.0.0.1:70000")), ["port '70000'"]),
    ("address-on-uart", doc(ep(**UART)[:-1] + f", {HERE}address: 127.0.0.1:1}}"),
     ["'address' does not apply to a uart endpoint"]),
    # --- durations per endpoint type ----------------------------------------------------------
    ("peer_timeout-on-client", doc(ep(mode="client")[:-1] + f", {HERE}peer_timeout: 1s}}"),
     ["'peer_timeout' does not apply to a udp client"]),
    ("peer_timeout-no-unit", doc(ep(peer_timeout=f"{HERE}30")), ["peer_timeout", "needs a unit"]),
    ("peer_timeout-zero", doc(ep(peer_timeout=f"{HERE}0ms")), ["greater than 0"]),
    ("reconnect_min-on-tcp-server", doc(ep(type="tcp")[:-1] + f", {HERE}reconnect_min: 1s}}"),
     ["'reconnect_min' does not apply to a tcp server"]),
    ("reconnect_min-word", doc(ep(**TCP_CLIENT, reconnect_min=f"{HERE}fast")),
     ["reconnect_min", "invalid duration 'fast'"]),
    ("reconnect_max-below-min", doc(ep(**TCP_CLIENT, reconnect_min="2s",
                                       reconnect_max=f"{HERE}1s")),
     ["'reconnect_max' (1s) must not be below 'reconnect_min' (2s)"]),
    ("reconnect_max-below-default-min", doc(ep(**UART, reconnect_max=f"{HERE}100ms")),
     ["'reconnect_max' (100ms) must not be below 'reconnect_min' (500ms)"]),
    ("reconnect_max-zero", doc(ep(**UART, reconnect_max=f"{HERE}0s")), ["greater than 0"]),
    # --- uart ---------------------------------------------------------------------------------
    ("device-missing", doc(f"{HERE}" + ep(**{**UART, "device": None})),
     ["missing required key 'device'"]),
    ("device-empty", doc(ep(**{**UART, "device": f'{HERE}""'})), ["'device' must not be empty"]),
    ("device-on-tcp", doc(ep(type="tcp")[:-1] + f", {HERE}device: /dev/ttyS0}}"),
     ["'device' does not apply to a tcp endpoint"]),
    ("baud-zero", doc(ep(**UART, baud=f"{HERE}0")), ["'baud': '0' is not a positive integer"]),
    ("baud-word", doc(ep(**UART, baud=f"{HERE}fast")), ["'baud': 'fast'"]),
    ("baud-too-big", doc(ep(**UART, baud=f"{HERE}5000000000")), ["'baud': '5000000000'"]),
    ("baud-on-udp", doc(UDP[:-1] + f", {HERE}baud: 57600}}"),
     ["'baud' does not apply to a udp endpoint"]),
    ("flow_control-maybe", doc(ep(**UART, flow_control=f"{HERE}maybe")),
     ["'flow_control' must be true or false, not 'maybe'"]),
    # --- tx_queue -------------------------------------------------------------------------
    ("tx_queue-word", doc(ep(tx_queue=f"{HERE}lots")), ["'tx_queue': 'lots' is not a size"]),
    ("tx_queue-too-small", doc(ep(tx_queue=f"{HERE}100")), ["below the minimum of 280"]),
    ("tx_queue-too-big", doc(ep(tx_queue=f"{HERE}65MiB")), ["at most 64MiB"]),
    ("tx_queue-negative", doc(ep(tx_queue=f"{HERE}-16k")), ["is not a size"]),
    # --- message filters ------------------------------------------------------------------
    ("allow_in-unknown-name", doc(ep(allow_in=f"[HEARTBEAT, {HERE}NOT_A_MESSAGE]")),
     ["'allow_in': unknown message 'NOT_A_MESSAGE'"]),
    ("block_in-id-too-big", doc(ep(block_in=f"[{HERE}16777216]")),
     ["'block_in': message id '16777216' out of range"]),
    ("allow_out-map-item", doc(ep(allow_out=f"[{HERE}{{id: 0}}]")),
     ["'allow_out': a message must be an id or a name"]),
    ("block_out-scalar", doc(ep(block_out=f"{HERE}HEARTBEAT")), ["'block_out' must be a sequence"]),
    ("block_out-negative", doc(ep(block_out=f"[{HERE}-1]")), ["message id '-1' out of range"]),
    # --- bonds ----------------------------------------------------------------------------
    ("bond-empty", doc(ep(bond=f'{HERE}""')), ["'bond' must not be empty"]),
    ("bond-undeclared", doc(ep(bond=f"{HERE}ghost")), ["bond 'ghost' is not declared"]),
    ("bonds-scalar", BONDED.replace("bonds:\n  - {name: v}", f"bonds: {HERE}v"),
     ["'bonds' must be a sequence"]),
    ("bond-scalar", BONDED + f"  - {HERE}w\n", ["bond #2", "map"]),
    ("bond-no-name", BONDED + f"  - {HERE}{{tx: active}}\n", ["bond #2", "'name'"]),
    ("bond-name-chars", BONDED + f"  - {{name: {HERE}'w x'}}\n", ["invalid name 'w x'"]),
    ("bond-unknown-key", BONDED.replace("{name: v}", f"{{name: v, {HERE}links: 2}}"),
     ["bond 'v': unknown key 'links'"]),
    ("bond-tx-invalid", BONDED.replace("{name: v}", f"{{name: v, tx: {HERE}all}}"),
     ["invalid tx 'all'", "broadcast, active"]),
    ("bond-duplicate", BONDED + f"  - {{name: {HERE}v}}\n", ["duplicate bond name 'v'"]),
    ("bond-no-member", BONDED + f"  - {{name: {HERE}w}}\n", ["bond 'w' has no member"]),
    # --- filters: the entry ---------------------------------------------------------------
    ("filters-scalar", BONDED + f"filters: {HERE}dedup\n", ["'filters' must be a sequence"]),
    ("filter-scalar", BONDED + f"filters:\n  - {HERE}dedup\n", ["filter #1", "map"]),
    ("filter-no-plugin", with_filter(f"{HERE}{{enabled: true}}"),
     ["missing required key 'plugin'"]),
    ("filter-plugin-chars", with_filter(f"{{plugin: {HERE}Dedup}}"),
     ["invalid plugin name 'Dedup'"]),
    ("filter-plugin-missing", with_filter(f"{HERE}{{plugin: nosuch}}"),
     ["filter 'nosuch'", "cannot load plugin"]),
    ("filter-enabled-maybe", with_filter(f"{{plugin: dedup, enabled: {HERE}maybe}}"),
     ["'enabled' must be true or false"]),
    ("filter-unknown-bond", with_filter(f"{{plugin: dedup, bonds: [{HERE}w]}}"),
     ["'bonds': unknown bond 'w'"]),
    ("filter-unknown-endpoint", with_filter(f"{{plugin: stats, endpoints: [r, {HERE}x]}}"),
     ["'endpoints': unknown endpoint 'x'"]),
    ("filter-endpoints-nested", with_filter(f"{{plugin: stats, endpoints: [{HERE}[r]]}}"),
     ["'endpoints': each item must be a name"]),
    ("filter-option-empty", BONDED + f"filters:\n  - plugin: dedup\n    {HERE}window:\n",
     ["option 'window' needs a value"]),
    ("filter-option-map", with_filter(f"{{plugin: dedup, window: {HERE}{{s: 2}}}}"),
     ["option 'window' must be a value or a sequence"]),
    ("filter-option-nested-item", with_filter(f"{{plugin: linkswitch, priority: [{HERE}[r]]}}"),
     ["option 'priority': items must be single values"]),
    # --- filters: plugin options (checked by the host against each plugin's declaration, or
    # by the plugin itself) --------------------------------------------------------------------
    ("dedup-unknown-option", with_filter(f"{{plugin: dedup, {HERE}colour: red}}"),
     ["unknown option 'colour'", "window"]),
    ("dedup-window-no-unit", with_filter(f"{{plugin: dedup, window: {HERE}2}}"),
     ["option 'window' must be a duration"]),
    ("dedup-hash-md5", with_filter(f"{{plugin: dedup, hash: {HERE}md5}}"),
     ["option 'hash'", "murmur3_128 or murmur3_32"]),
    ("dedup-key-bytes", with_filter(f"{{plugin: dedup, key: {HERE}bytes}}"),
     ["option 'key'", "frame or content"]),
    ("dedup-drop_stale-yes", with_filter(f"{{plugin: dedup, drop_stale: {HERE}yes}}"),
     ["option 'drop_stale' must be true or false"]),
    ("dedup-max_entries-zero", with_filter(f"{{plugin: dedup, max_entries: {HERE}0}}"),
     ["option 'max_entries'", "between 1 and"]),
    ("dedup-max_entries-word", with_filter(f"{{plugin: dedup, max_entries: {HERE}many}}"),
     ["option 'max_entries' must be an integer"]),
    ("linkswitch-max_loss-word", with_filter(f"{{plugin: linkswitch, max_loss: {HERE}five}}"),
     ["option 'max_loss' must be a percentage"]),
    ("linkswitch-max_loss-over", with_filter(f"{{plugin: linkswitch, max_loss: {HERE}150%}}"),
     ["option 'max_loss' must be a percentage"]),
    ("linkswitch-switch_after-zero", with_filter(f"{{plugin: linkswitch, switch_after: {HERE}0s}}"),
     ["option 'switch_after'", "greater than 0"]),
    ("linkswitch-loss_window-zero", with_filter(f"{{plugin: linkswitch, loss_window: {HERE}0ms}}"),
     ["option 'loss_window'", "greater than 0"]),
    ("linkswitch-priority-twice", with_filter(f"{{plugin: linkswitch, priority: {HERE}[r, l, r]}}"),
     ["option 'priority'", "'r' is listed twice"]),
    ("linkswitch-priority-scalar", with_filter(f"{{plugin: linkswitch, priority: {HERE}r}}"),
     ["option 'priority' must be a list of strings"]),
    ("linkswitch-hold_down-word", with_filter(f"{{plugin: linkswitch, hold_down: {HERE}long}}"),
     ["option 'hold_down' must be a duration"]),
    ("linkswitch-failback_after-list",
     with_filter(f"{{plugin: linkswitch, failback_after: {HERE}[1s]}}"),
     ["option 'failback_after' must be a duration"]),
    ("stats-interval-zero", with_filter(f"{{plugin: stats, interval: {HERE}0s}}"),
     ["option 'interval'", "greater than 0"]),
    ("stats-csv-unwritable", with_filter(f"{{plugin: stats, csv: {HERE}/nonexistent/dir/s.csv}}"),
     ["option 'csv'", "cannot open"]),
    ("stats-log-yes", with_filter(f"{{plugin: stats, log: {HERE}yes}}"),
     ["option 'log' must be true or false"]),
]


def locate(text: str):
    """(text without the marker, 1-based line, 1-based column of the marker)."""
    assert text.count(HERE) == 1, "a case marks exactly one place"
    before = text[:text.index(HERE)]
    line = before.count("\n") + 1
    column = len(before) - (before.rfind("\n") + 1) + 1
    return text.replace(HERE, ""), line, column


def test_cases_cover_every_key():
    """Every key the loader takes (top level, endpoint, bond, filter entry) has a case."""
    keys = ["log_level", "unknown_messages", "route_timeout", "report_interval", "plugin_dir",
            "status_socket", "endpoints", "bonds", "filters", "name", "type", "mode", "address",
            "peer_timeout", "reconnect_min", "reconnect_max", "device", "baud", "flow_control",
            "tx_queue", "allow_in", "block_in", "allow_out", "block_out", "bond", "tx", "plugin",
            "enabled"]
    ids = " ".join(c[0] for c in CASES)
    missing = [k for k in keys if k not in ids]
    print(f"\n{len(CASES)} cases, each run with --check-config and as a normal start")
    assert not missing, f"no case for {missing}"
    assert len(CASES) >= 50


@pytest.mark.parametrize("text,words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
@pytest.mark.parametrize("check", [True, False], ids=["check-config", "start"])
def test_config_error(mavbond_bin, plugin_dir, tmp_path, text, words, check):
    body, line, column = locate(text)
    path = tmp_path / "bad.yaml"
    path.write_text(body)
    args = [mavbond_bin, "-c", str(path), "--plugin-dir", plugin_dir]
    r = subprocess.run(args + (["--check-config"] if check else []), capture_output=True,
                       text=True, timeout=10)
    print(f"\nexit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == 78, f"exit {r.returncode} (a negative code is a signal): {r.stderr}"
    first = r.stderr.splitlines()[0] if r.stderr else ""
    where = f"{path}:{line}:{column}: "
    assert first.startswith(where), f"expected {where!r} at the start of stderr: {r.stderr!r}"
    for w in words:
        assert w in first, f"{w!r} not in {first!r}"
    assert r.stdout == "", "nothing is printed on stdout for an invalid config"
    assert "running with" not in r.stderr
