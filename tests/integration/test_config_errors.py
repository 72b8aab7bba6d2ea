"""Every kind of config error, against the real binary: --check-config and a normal start both
exit with exactly 78 (EX_CONFIG, not a signal), and stderr starts with the exact
"file:line:column: " of the fault, then says what is wrong. The cases cover every key the
loader knows (src/config/config.cpp) and the options of the three plugins.

A case is (id, YAML text, words the message must contain). The text marks the fault with »:
the marker is removed before the file is written, and its place is the line and column the
message must name. (tests/unit/config checks the loader's messages in-process; this checks
what an operator sees from the daemon.) Every case also has the key files of KEY_FILES next
to the config, so a `signing:` block can name a valid key and fail on something else. The
list of keys a case must cover is read from the loader's and the plugins' sources
(loader_keys(), plugin_options()), so a key merged later without a case fails the meta-test."""
from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

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
TLOG = dict(type="tlog", mode=None, address=None, directory="logs")
# Written next to the config for every case (a relative key_file is read from there).
KEY_FILES = {"good.key": ("ab" * 32 + "\n", 0o600)}
BONDED = doc(ep(name="r", bond="v"), ep(name="l", address="127.0.0.1:14551", bond="v"),
             tail="bonds:\n  - {name: v}\n")


def metered(lte: dict = {}, bond: str = "") -> str:
    """A bond v of a free member r and a metered member l (with `lte`'s keys), the bond with
    `bond`'s keys."""
    return doc(ep(name="r", bond="v"),
               ep(name="l", address="127.0.0.1:14551", bond="v", **{"cost": "metered", **lte}),
               tail="bonds:\n  - {name: v" + bond + "}\n")


def with_filter(entry: str) -> str:
    return BONDED + "filters:\n  - " + entry + "\n"


CASES = [
    # --- the document ----------------------------------------------------------------------
    ("empty-file", f"{HERE}", ["empty"]),
    ("top-is-a-list", f"{HERE}- a\n- b\n", ["top level must be a map"]),
    ("yaml-syntax", f"log_level: info\nendpoints: [{{name: a\n{HERE}", []),
    # yaml-cpp's own words come last, after what is wrong in plain words (issue 21, item 11)
    ("yaml-indented-deeper", f"endpoints:\n  - name: a\n     type{HERE}: udp\n",
     ["this line's key (column 6) is indented deeper than the key above it (column 5)",
      "the keys of one map start in the same column (YAML: illegal map value)"]),
    ("yaml-indented-less", f"endpoints:\n  - name: a\n  {HERE}type: udp\n",
     ["this line's key (column 3) lines up with no map above it (the key above starts at column 5)",
      "(YAML: end of map not found)"]),
    ("yaml-colon-in-value", f"endpoints:\n  - name: a\n    address: 127.0.0.1:14550{HERE}: x\n",
     ["a value that holds ': ' must be quoted", "(YAML: illegal map value)"]),
    ("yaml-unclosed-brace", f"endpoints:\n  - {{name: a, type: udp\n  - {HERE}{{name: b}}\n",
     ["a '{' before this has no closing '}' (YAML: end of map flow not found)"]),
    ("yaml-tab", f"endpoints:\n\t{HERE}- name: a\n",
     ["this line is indented with a tab: YAML indents with spaces only"]),
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
    # --- identity: mavbond's own MAVLink identity ---------------------------------------------
    ("identity-scalar", doc(UDP, top=f"identity: {HERE}1\n"),
     ["identity: must be a map of keys, not a scalar"]),
    ("identity-unknown-key", doc(UDP, top=f"identity:\n  {HERE}system: 1\n"),
     ["identity: unknown key 'system'"]),
    ("identity-sysid-zero", doc(UDP, top=f"identity:\n  sysid: {HERE}0\n"),
     ["identity: 'sysid': '0' is not a MAVLink id (1..255)"]),
    ("identity-sysid-negative", doc(UDP, top=f"identity: {{sysid: {HERE}-1}}\n"),
     ["identity: 'sysid': '-1' is not a MAVLink id"]),
    ("identity-compid-too-big", doc(UDP, top=f"identity:\n  compid: {HERE}256\n"),
     ["identity: 'compid': '256' is not a MAVLink id (1..255)"]),
    ("identity-compid-list", doc(UDP, top=f"identity: {{compid: {HERE}[1]}}\n"),
     ["identity: 'compid' must be a single value, not a sequence"]),
    ("identity-heartbeat-zero", doc(UDP, top=f"identity:\n  heartbeat: {HERE}0s\n"),
     ["identity: 'heartbeat': duration must be greater than 0"]),
    ("identity-heartbeat-no-unit", doc(UDP, top=f"identity:\n  heartbeat: {HERE}1\n"),
     ["identity: 'heartbeat': duration '1' needs a unit"]),
    # --- transmit budgets: tx_rate on an endpoint, tx_classes ---------------------------------
    ("endpoint-tx_rate-no-unit", doc(ep(tx_rate=f"{HERE}5000")),
     ["'tx_rate': '5000' is not a rate (e.g. 5kB/s"]),
    ("endpoint-tx_rate-baud-on-udp", doc(ep(tx_rate=f"{HERE}baud")),
     ["'baud' takes a UART's own baudrate"]),
    ("endpoint-tx_rate-too-slow", doc(ep(**UART, tx_rate=f"{HERE}300baud")),
     ["'tx_rate': 300baud is outside 100 B/s"]),
    ("tlog-tx_rate", doc(ep(**TLOG, **{f"{HERE}tx_rate": "5kB/s"})),
     ["key 'tx_rate' does not apply to a tlog endpoint"]),
    # --- radio_status: a SiK radio's reports set the budget ---------------------------------
    ("endpoint-radio_status-unknown-radio",
     doc(ep(**UART, bond="v", radio_status=f"{HERE}rfd900"), tail="bonds:\n  - {name: v}\n"),
     ["'radio_status': 'rfd900' is not a radio mavbond knows (sik:"]),
    ("endpoint-radio_status-list",
     doc(ep(**UART, bond="v", radio_status=f"{HERE}[sik]"), tail="bonds:\n  - {name: v}\n"),
     ["'radio_status' must be a single value"]),
    ("endpoint-radio_status-udp-client-without-tx_rate",
     doc(ep(mode="client", bond="v", radio_status=f"{HERE}sik"), tail="bonds:\n  - {name: v}\n"),
     ["'radio_status' on a udp client endpoint needs 'tx_rate'"]),
    ("endpoint-radio_status-on-a-server",
     doc(ep(bond="v", tx_rate="57600baud", radio_status=f"{HERE}sik"),
         tail="bonds:\n  - {name: v}\n"),
     ["'radio_status' does not apply to a udp server endpoint (each peer is a link"]),
    ("endpoint-radio_status-not-in-a-bond", doc(ep(**UART, radio_status=f"{HERE}sik")),
     ["endpoint 'a': 'radio_status' needs the endpoint in a bond"]),
    ("tlog-radio_status", doc(ep(**TLOG, **{f"{HERE}radio_status": "sik"})),
     ["key 'radio_status' does not apply to a tlog endpoint"]),
    ("tx_classes-scalar", doc(UDP, top=f"tx_classes: {HERE}yes\n"),
     ["tx_classes: must be a map of keys, not a scalar"]),
    ("tx_classes-unknown-key", doc(UDP, top=f"tx_classes:\n  {HERE}commands: [0]\n"),
     ["tx_classes: unknown key 'commands'"]),
    ("tx_classes-control-unknown-message",
     doc(UDP, top=f"tx_classes:\n  control: [{HERE}NOPE]\n"),
     ["tx_classes: 'control': unknown message 'NOPE'"]),
    ("tx_classes-bulk-also-control",
     doc(UDP, top=f"tx_classes:\n  bulk: {HERE}[HEARTBEAT]\n"),
     ["message HEARTBEAT (0) is in both control and bulk"]),
    ("tx_classes-caps-on-control",
     doc(UDP, top=f"tx_classes:\n  caps: {{{HERE}COMMAND_LONG: 1Hz}}\n"),
     ["a cap thins telemetry; this message is control"]),
    ("tx_classes-caps-not-hz",
     doc(UDP, top=f"tx_classes:\n  caps: {{ATTITUDE: {HERE}100ms}}\n"),
     ["'100ms' is not a rate in Hz"]),
    # --- link_events ----------------------------------------------------------------------
    ("link_events-empty", doc(UDP, top=f"{HERE}link_events:\n"),
     ["link_events: must be a map of keys, not nothing"]),
    ("link_events-list", doc(UDP, top=f"link_events: {HERE}[statustext]\n"),
     ["link_events: must be a map of keys, not a sequence"]),
    ("link_events-unknown-key", doc(UDP, top=f"link_events:\n  {HERE}lost_after: 1s\n"),
     ["link_events: unknown key 'lost_after'"]),
    ("link_events-duplicate-key",
     doc(UDP, top=f"link_events:\n  statustext: true\n  {HERE}statustext: false\n"),
     ["link_events: duplicate key 'statustext'"]),
    ("link_events-statustext-maybe", doc(UDP, top=f"link_events:\n  statustext: {HERE}maybe\n"),
     ["link_events: 'statustext' must be true or false, not 'maybe'"]),
    ("link_events-silent_after-zero", doc(UDP, top=f"link_events:\n  silent_after: {HERE}0s\n"),
     ["link_events: 'silent_after': duration must be greater than 0"]),
    ("link_events-silent_after-no-unit",
     doc(UDP, top=f"link_events:\n  silent_after: {HERE}1\n"),
     ["link_events: 'silent_after': duration '1' needs a unit"]),
    ("link_events-min_interval-word", doc(UDP, top=f"link_events:\n  min_interval: {HERE}often\n"),
     ["link_events: 'min_interval': invalid duration 'often'"]),
    ("link_events-min_interval-negative",
     doc(UDP, top=f"link_events:\n  min_interval: {HERE}-2s\n"),
     ["link_events: 'min_interval': invalid duration '-2s'"]),
    # --- metrics: the Prometheus endpoint ----------------------------------------------------
    ("metrics-scalar", doc(UDP, top=f"metrics: {HERE}9273\n"),
     ["'metrics' must be a map of keys (listen, timeout, max_connections), not a scalar"]),
    ("metrics-listen-missing", doc(UDP, top=f"metrics: {HERE}{{timeout: 1s}}\n"),
     ["metrics: missing required key 'listen'"]),
    ("metrics-listen-missing-block", doc(UDP, top=f"metrics:\n  {HERE}timeout: 1s\n"),
     ["metrics: missing required key 'listen'"]),
    ("metrics-listen-empty", doc(UDP, top=f"metrics:\n  {HERE}listen:\n"),
     ["metrics: 'listen' needs a value"]),
    ("metrics-listen-hostname", doc(UDP, top=f"metrics: {{listen: {HERE}example.com:9273}}\n"),
     ["metrics: 'listen': host 'example.com' is not an IPv4 address"]),
    ("metrics-listen-port-zero", doc(UDP, top=f"metrics: {{listen: {HERE}127.0.0.1:0}}\n"),
     ["metrics: 'listen': port '0' is not in 1..65535"]),
    ("metrics-listen-port-only-big", doc(UDP, top=f"metrics: {{listen: {HERE}70000}}\n"),
     ["metrics: 'listen': port '70000' is not in 1..65535"]),
    ("metrics-listen-word", doc(UDP, top=f"metrics: {{listen: {HERE}http}}\n"),
     ["metrics: 'listen': port 'http' is not in 1..65535"]),
    ("metrics-unknown-key", doc(UDP, top=f"metrics: {{listen: 9273, {HERE}port: 9273}}\n"),
     ["metrics: unknown key 'port'"]),
    ("metrics-timeout-zero", doc(UDP, top=f"metrics: {{listen: 9273, timeout: {HERE}0s}}\n"),
     ["metrics: 'timeout': duration must be greater than 0"]),
    ("metrics-timeout-no-unit", doc(UDP, top=f"metrics: {{listen: 9273, timeout: {HERE}5}}\n"),
     ["metrics: 'timeout': duration '5' needs a unit"]),
    ("metrics-max_connections-zero",
     doc(UDP, top=f"metrics: {{listen: 9273, max_connections: {HERE}0}}\n"),
     ["metrics: 'max_connections': '0' is not in 1..1024"]),
    ("metrics-max_connections-too-big",
     doc(UDP, top=f"metrics: {{listen: 9273, max_connections: {HERE}1025}}\n"),
     ["metrics: 'max_connections': '1025' is not in 1..1024"]),
    ("metrics-max_connections-word",
     doc(UDP, top=f"metrics: {{listen: 9273, max_connections: {HERE}many}}\n"),
     ["metrics: 'max_connections': 'many' is not in 1..1024"]),
    # --- endpoints: shape and names ----------------------------------------------------------
    ("endpoint-scalar", f"endpoints:\n  - {HERE}udp\n", ["endpoint #1", "map"]),
    ("endpoint-no-name", doc(UDP, f"{HERE}" + ep(name=None)), ["endpoint #2", "'name'"]),
    ("endpoint-name-empty", doc(ep(name=f'{HERE}""')), ["'name' must not be empty"]),
    ("endpoint-name-chars", doc(ep(name=f"{HERE}a/b")), ["invalid name 'a/b'"]),
    ("endpoint-name-duplicate", doc(UDP, ep(name=f"{HERE}a", address="127.0.0.1:1")),
     ["duplicate endpoint name 'a'"]),
    ("endpoint-unknown-key", doc(UDP[:-1] + f", {HERE}colour: red}}"), ["unknown key 'colour'"]),
    ("endpoint-unknown-key-typo", doc(ep(**UART)[:-1] + f", {HERE}buad: 57600}}"),
     ["unknown key 'buad' (did you mean 'baud'? a uart endpoint takes: ",
      "allow_in, allow_out, baud, block_in"]),
    ("endpoint-duplicate-key", doc(UDP[:-1] + f", {HERE}mode: client}}"), ["duplicate key 'mode'"]),
    ("type-missing", doc(f"{HERE}" + ep(type=None)),
     ["missing required key 'type' (udp, tcp, uart or tlog)"]),
    ("type-invalid", doc(ep(type=f"{HERE}serial")),
     ["invalid type 'serial'", "udp, tcp, uart, tlog"]),
    ("mode-missing", doc(f"{HERE}" + ep(mode=None)), ["missing required key 'mode'"]),
    ("mode-invalid", doc(ep(mode=f"{HERE}listen")), ["invalid mode 'listen'"]),
    # --- address ----------------------------------------------------------------------------
    ("address-missing", doc(f"{HERE}" + ep(address=None)), ["missing required key 'address'"]),
    ("address-no-port", doc(ep(address=f"{HERE}127.0.0.1")), ["needs host:port"]),
    ("address-bad-hostname", doc(ep(address=f"{HERE}gcs_lan:14550")),
     ["host 'gcs_lan' is not an IPv4 address (a.b.c.d), an IPv6 address in brackets or a host "
      "name"]),
    ("address-bad-ipv4", doc(ep(address=f"{HERE}10.0.300.1:14550")),
     ["host '10.0.300.1' is not an IPv4 address"]),
    ("address-ipv6-bare", doc(ep(address=f"{HERE}'::1:14550'")),
     ["host '::1': an IPv6 address is written in brackets ([::1]:port)"]),
    ("address-ipv6-bad", doc(ep(address=f"{HERE}'[::g]:14550'")),
     ["'[::g]' is not an IPv6 address"]),
    ("address-ipv6-no-port", doc(ep(address=f"{HERE}'[::1]'")),
     ["'[::1]' needs a port after the brackets"]),
    ("address-ipv6-unclosed", doc(ep(address=f"{HERE}'[::1:14550'")), ["has no ']'"]),
    ("address-ipv6-port-zero", doc(ep(address=f"{HERE}'[::1]:0'")), ["port '0'"]),
    ("address-ipv6-unquoted", doc(ep(address=f"{HERE}[::1]")),
     ["'address' is a list: an IPv6 address in brackets is quoted in YAML"]),
    ("address-port-zero", doc(ep(address=f"{HERE}127.0.0.1:0")), ["port '0'"]),
    ("address-scheme-prefix", doc(ep(address=f'{HERE}"udp:127.0.0.1:14550"')),
     ["'udp:127.0.0.1:14550': drop the 'udp:' prefix (the endpoint's type and mode say that "
      "here): address: 127.0.0.1:14550"]),
    ("address-url", doc(ep(address=f'{HERE}"tcp://gcs.example.net:5760"')),
     ["drop the 'tcp://' prefix", "address: gcs.example.net:5760"]),
    ("address-port-big", doc(ep(address=f"{HERE}127.0.0.1:70000")), ["port '70000'"]),
    ("address-on-uart", doc(ep(**UART)[:-1] + f", {HERE}address: 127.0.0.1:1}}"),
     ["'address' does not apply to a uart endpoint"]),
    # --- durations per endpoint type ----------------------------------------------------------
    ("peer_timeout-on-client", doc(ep(mode="client")[:-1] + f", {HERE}peer_timeout: 1s}}"),
     ["'peer_timeout' does not apply to a udp client"]),
    ("peer_timeout-no-unit", doc(ep(peer_timeout=f"{HERE}30")), ["peer_timeout", "needs a unit"]),
    ("peer_timeout-zero", doc(ep(peer_timeout=f"{HERE}0ms")), ["greater than 0"]),
    ("idle_timeout-no-unit", doc(ep(type="tcp", idle_timeout=f"{HERE}30")),
     ["idle_timeout", "needs a unit"]),
    ("idle_timeout-on-udp", doc(UDP[:-1] + f", {HERE}idle_timeout: 1s}}"),
     ["key 'idle_timeout' does not apply to a udp endpoint"]),
    ("max_clients_per_address-zero", doc(ep(type="tcp", max_clients_per_address=f"{HERE}0")),
     ["'max_clients_per_address': '0' is not a positive integer"]),
    ("max_clients_per_address-on-tcp-client",
     doc(ep(**TCP_CLIENT)[:-1] + f", {HERE}max_clients_per_address: 2}}"),
     ["'max_clients_per_address' does not apply to a tcp client"]),
    # Two servers on one address (issue 21): the second is refused, naming the first.
    ("address-taken", doc(UDP, ep(name="b", address=f"{HERE}127.0.0.1:14550")),
     ["endpoint 'b': udp address 127.0.0.1:14550 is taken by endpoint 'a' (127.0.0.1:14550, "
      "declared at ", ":2:5): two servers cannot listen on one address"]),
    ("address-taken-by-wildcard", doc(UDP, ep(name="b", address=f"{HERE}0.0.0.0:14550")),
     ["endpoint 'b': udp address 0.0.0.0:14550 is taken by endpoint 'a' (127.0.0.1:14550"]),
    ("address-taken-dual-stack", doc(ep(type="tcp", address="0.0.0.0:5760"),
                                     ep(name="b", type="tcp", address=f"{HERE}'[::]:5760'")),
     ["endpoint 'b': tcp address [::]:5760 is taken by endpoint 'a' (0.0.0.0:5760"]),
    ("rx_buffer-word", doc(ep(rx_buffer=f"{HERE}huge")),
     ["'rx_buffer': 'huge' is not a size between 64KiB and 1GiB"]),
    ("rx_buffer-too-small", doc(ep(rx_buffer=f"{HERE}4096")),
     ["'rx_buffer': '4096' is not a size between 64KiB and 1GiB"]),
    ("rx_buffer-on-uart", doc(ep(**UART)[:-1] + f", {HERE}rx_buffer: 1MiB}}"),
     ["key 'rx_buffer' does not apply to a uart endpoint"]),
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
    ("reconnect_max-below-min-udp-client", doc(ep(mode="client", reconnect_min="2s",
                                                  reconnect_max=f"{HERE}1s")),
     ["'reconnect_max' (1s) must not be below 'reconnect_min' (2s)"]),
    ("resolve_interval-word", doc(ep(mode="client", resolve_interval=f"{HERE}often")),
     ["resolve_interval", "invalid duration 'often'"]),
    ("resolve_interval-no-unit", doc(ep(**TCP_CLIENT, resolve_interval=f"{HERE}60")),
     ["resolve_interval", "needs a unit"]),
    ("resolve_interval-zero", doc(ep(**TCP_CLIENT, resolve_interval=f"{HERE}0s")),
     ["greater than 0"]),
    ("resolve_interval-on-server", doc(ep()[:-1] + f", {HERE}resolve_interval: 1s}}"),
     ["'resolve_interval' does not apply to a udp server"]),
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
    # --- tlog (a flight log: only what is routed to it) ----------------------------------------
    ("tlog-directory-missing", doc(f"{HERE}" + ep(**{**TLOG, "directory": None})),
     ["endpoint 'a': missing required key 'directory'"]),
    ("tlog-directory-empty", doc(ep(**{**TLOG, "directory": f'{HERE}""'})),
     ["'directory' must not be empty"]),
    ("tlog-directory-list", doc(ep(**{**TLOG, "directory": f"{HERE}[a, b]"})),
     ["'directory' must be a single value, not a sequence"]),
    ("tlog-max_size-word", doc(ep(**TLOG, max_size=f"{HERE}big")),
     ["'max_size': 'big' is not a size in bytes"]),
    ("tlog-max_size-too-small", doc(ep(**TLOG, max_size=f"{HERE}4095")),
     ["'max_size': 4095 is below the minimum of 4096 bytes"]),
    ("tlog-max_size-zero", doc(ep(**TLOG, max_size=f"{HERE}0")),
     ["'max_size': 0 is below the minimum of 4096 bytes"]),
    ("tlog-mode", doc(ep(**TLOG)[:-1] + f", {HERE}mode: server}}"),
     ["key 'mode' does not apply to a tlog endpoint"]),
    ("tlog-allow_in", doc(ep(**TLOG)[:-1] + f", {HERE}allow_in: [HEARTBEAT]}}"),
     ["key 'allow_in' does not apply to a tlog endpoint"]),
    ("tlog-block_in", doc(ep(**TLOG)[:-1] + f", {HERE}block_in: [0]}}"),
     ["key 'block_in' does not apply to a tlog endpoint"]),
    ("tlog-bond", doc(ep(**TLOG)[:-1] + f", {HERE}bond: v}}"),
     ["key 'bond' does not apply to a tlog endpoint"]),
    ("directory-on-udp", doc(UDP[:-1] + f", {HERE}directory: logs}}"),
     ["key 'directory' does not apply to a udp endpoint"]),
    ("max_size-on-uart", doc(ep(**UART)[:-1] + f", {HERE}max_size: 1MiB}}"),
     ["key 'max_size' does not apply to a uart endpoint"]),
    # --- signing (key-file contents and modes: test_signing.py, BAD_KEYS) -------------------
    ("endpoint-signing-scalar", doc(ep(signing=f"{HERE}on")),
     ["endpoint 'a': 'signing': must be a map (key_file, require), not a scalar"]),
    ("signing-empty", "endpoints:\n  - name: a\n    type: udp\n    mode: server\n"
                      f"    address: 127.0.0.1:14550\n    {HERE}signing:\n",
     ["'signing': must be a map", "not nothing"]),
    ("signing-key_file-missing", doc(ep(signing=f"{HERE}{{require: false}}")),
     ["'signing': missing required key 'key_file'"]),
    ("signing-key_file-empty", doc(ep(signing=f'{{key_file: {HERE}""}}')),
     ["'signing': 'key_file' must not be empty"]),
    ("signing-key_file-list", doc(ep(signing=f"{{key_file: {HERE}[good.key]}}")),
     ["'signing': 'key_file' must be a single value, not a sequence"]),
    ("signing-key_file-directory", doc(ep(signing=f"{{key_file: {HERE}/}}")),
     ["'signing': key file /: not a regular file"]),
    ("signing-require-maybe", doc(ep(signing=f"{{key_file: good.key, require: {HERE}maybe}}")),
     ["'signing': 'require' must be true or false, not 'maybe'"]),
    ("signing-unknown-key", doc(ep(signing=f"{{key_file: good.key, {HERE}algorithm: sha256}}")),
     ["'signing': unknown key 'algorithm'"]),
    ("signing-duplicate-key",
     doc(ep(signing=f"{{key_file: good.key, {HERE}key_file: good.key}}")),
     ["'signing': duplicate key 'key_file'"]),
    ("signing-on-tlog", doc(ep(**TLOG)[:-1] + f", {HERE}signing: {{key_file: good.key}}}}"),
     ["key 'signing' does not apply to a tlog endpoint"]),
    # --- a bond's signing -------------------------------------------------------------------
    ("bond-signing-scalar", BONDED.replace("{name: v}", f"{{name: v, signing: {HERE}on}}"),
     ["bond 'v': 'signing': must be a map (key_file, links), not a scalar"]),
    ("bond_signing-key_file-missing",
     BONDED.replace("{name: v}", f"{{name: v, signing: {HERE}{{links: [l]}}}}"),
     ["bond 'v': 'signing': missing required key 'key_file'"]),
    ("bond_signing-key_file-no-such-file",
     BONDED.replace("{name: v}", f"{{name: v, signing: {{key_file: {HERE}none.key}}}}"),
     ["none.key: cannot open: No such file or directory (make one with: mavbondctl keygen"]),
    ("bond_signing-links-not-a-member",
     BONDED.replace("{name: v}", f"{{name: v, signing: {{key_file: good.key, links: [{HERE}a]}}}}"),
     ["bond 'v': 'signing': 'links': 'a' is not a member of the bond"]),
    ("bond_signing-links-empty",
     BONDED.replace("{name: v}", f"{{name: v, signing: {{key_file: good.key, links: {HERE}[]}}}}"),
     ["'links' must name at least one member"]),
    ("bond_signing-links-twice",
     BONDED.replace("{name: v}", f"{{name: v, signing: {{key_file: good.key, links: [l, {HERE}l]}}}}"),
     ["'links': 'l' is listed twice"]),
    ("bond_signing-unknown-key",
     BONDED.replace("{name: v}", f"{{name: v, signing: {{key_file: good.key, {HERE}require: true}}}}"),
     ["bond 'v': 'signing': unknown key 'require'"]),
    ("endpoint-signing-on-a-bond-member",
     doc(ep(name="r", bond="v"),
         ep(name="l", address="127.0.0.1:14551", bond="v")[:-1] +
         f", {HERE}signing: {{key_file: good.key}}}}", tail="bonds:\n  - {name: v}\n"),
     ["endpoint 'l': 'signing' on a bond member: sign the bond instead"]),
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
    ("bond-renumber-maybe", BONDED.replace("{name: v}", f"{{name: v, renumber: {HERE}maybe}}"),
     ["bond 'v': 'renumber' must be true or false, not 'maybe'"]),
    # renumbering needs some filter that places every link's copies in one numbering: dedup,
    # with either key (key: frame places copies too)
    ("bond-renumber-no-dedup", BONDED.replace("{name: v}", f"{{name: v, renumber: {HERE}true}}"),
     ["bond 'v': 'renumber' needs a dedup filter on this bond, enabled"]),
    ("bond-renumber-dedup-disabled",
     BONDED.replace("{name: v}", f"{{name: v, renumber: {HERE}true}}")
     + "filters:\n  - {plugin: dedup, key: content, enabled: false}\n",
     ["bond 'v': 'renumber' needs a dedup filter on this bond, enabled"]),
    # tx: active sends on the link linkswitch chooses: without one, on every link (issue 21,
    # item 12)
    ("bond-tx-active-no-linkswitch", BONDED.replace("{name: v}", f"{{name: v, tx: {HERE}active}}"),
     ["bond 'v': 'tx: active' needs a linkswitch filter on this bond"]),
    ("bond-tx-active-linkswitch-disabled",
     BONDED.replace("{name: v}", f"{{name: v, tx: {HERE}active}}")
     + "filters:\n  - {plugin: linkswitch, enabled: false}\n",
     ["'tx: active' needs a linkswitch filter", "without one the bond would send on every link"]),
    # --- standby: a metered member (cost, standby_carries) and its bond's thresholds ---------
    ("endpoint-cost-invalid", metered({"cost": f"{HERE}cheap"}),
     ["endpoint 'l'", "invalid cost 'cheap'", "free, metered"]),
    ("endpoint-cost-no-bond", doc(ep(**{f"{HERE}cost": "metered"})),
     ["endpoint 'a': 'cost' needs 'bond'"]),
    ("endpoint-standby_carries-unknown", metered({"standby_carries": f"[control, {HERE}video]"}),
     ["'standby_carries': unknown class 'video'", "control, telemetry, bulk"]),
    ("endpoint-standby_carries-empty", metered({"standby_carries": f"{HERE}[]"}),
     ["'standby_carries' must name at least one class"]),
    ("endpoint-standby_carries-not-metered",
     doc(ep(name="r", bond="v"),
         ep(name="l", address="127.0.0.1:14551", bond="v",
            **{f"{HERE}standby_carries": "[control]"}), tail="bonds:\n  - {name: v}\n"),
     ["'standby_carries' applies only with 'cost: metered'"]),
    ("endpoint-standby_carries-scalar", metered({"standby_carries": f"{HERE}control"}),
     ["'standby_carries'", "sequence"]),
    ("bond-cost-every-member-metered",
     doc(ep(name="r", bond="v", cost="metered"),
         ep(name="l", address="127.0.0.1:14551", bond="v", cost="metered"),
         tail=f"bonds:\n  - {{name: {HERE}v}}\n"),
     ["bond 'v': every member is 'cost: metered'"]),
    ("bond-failover_loss-not-percent", metered(bond=f", failover_loss: {HERE}ten"),
     ["bond 'v': 'failover_loss': 'ten' is not a percentage"]),
    ("bond-failover_loss-over-100", metered(bond=f", failover_loss: {HERE}120%"),
     ["'failover_loss': '120%' is not a percentage from 0% to 100%"]),
    ("bond-failover_loss-no-metered-member",
     BONDED.replace("{name: v}", f"{{name: v, {HERE}failover_loss: 10%}}"),
     ["bond 'v': 'failover_loss' applies only to a bond with a 'cost: metered' member"]),
    ("bond-failback_loss-above-failover",
     metered(bond=f", failover_loss: 5%, failback_loss: {HERE}8%"),
     ["'failback_loss' must be below 'failover_loss' (5%)"]),
    ("bond-failback_loss-not-percent", metered(bond=f", failback_loss: {HERE}0.02"),
     ["'failback_loss': '0.02' is not a percentage"]),
    ("bond-failback_after-no-unit", metered(bond=f", failback_after: {HERE}10"),
     ["'failback_after': duration '10' needs a unit"]),
    ("bond-resend-too-long", metered(bond=f", resend: {HERE}1m"),
     ["'resend': at most 10s"]),
    ("bond-resend-invalid", metered(bond=f", resend: {HERE}soon"),
     ["'resend': invalid duration 'soon'"]),
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
    ("filter-bonds-unknown", with_filter(f"{{plugin: dedup, bonds: [{HERE}w]}}"),
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
    ("dedup-stale_after-no-unit", with_filter(f"{{plugin: dedup, stale_after: {HERE}250}}"),
     ["option 'stale_after' must be a duration"]),
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
    ("linkswitch-switch_margin-word",
     with_filter(f"{{plugin: linkswitch, switch_margin: {HERE}five}}"),
     ["option 'switch_margin' must be a percentage"]),
    ("linkswitch-priority-unknown",
     with_filter(f"{{plugin: linkswitch, bonds: [v], priority: [r, {HERE}x]}}"),
     ["option 'priority': 'x' is not an endpoint of bond v (r, l)"]),
    ("linkswitch-priority-unknown-unscoped",
     with_filter(f"{{plugin: linkswitch, priority: [{HERE}radoi, l]}}"),
     ["option 'priority': 'radoi' is not an endpoint of bond v (r, l)"]),
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


REPO = Path(__file__).resolve().parents[2]
LOADER = REPO / "src" / "config" / "config.cpp"

# What the derivations below must find at least: the keys known when this was written. A
# loader or plugin rewritten so that the regexes miss its keys fails here, not silently.
KNOWN_KEYS = {
    "top": {"log_level", "unknown_messages", "route_timeout", "report_interval", "plugin_dir",
            "status_socket", "endpoints", "bonds", "filters", "identity", "link_events",
            "metrics", "tx_classes"},
    "endpoint": {"name", "type", "mode", "address", "peer_timeout", "reconnect_min",
                 "reconnect_max", "resolve_interval", "device", "baud", "flow_control", "tx_queue", "allow_in",
                 "block_in", "allow_out", "block_out", "bond", "signing", "directory",
                 "max_size", "rx_buffer", "tx_rate", "radio_status", "cost",
                 "standby_carries", "idle_timeout", "max_clients_per_address"},
    "signing": {"key_file", "require"},
    "bond": {"name", "tx", "renumber", "failover_loss", "failback_loss", "failback_after",
             "resend", "signing"},
    "bond_signing": {"key_file", "links"},
    "filter": {"plugin", "enabled", "bonds", "endpoints"},
    "metrics": {"listen", "timeout", "max_connections"},
    "identity": {"sysid", "compid", "heartbeat"},
    "link_events": {"statustext", "silent_after", "min_interval"},
    "tx_classes": {"control", "bulk", "caps"},
}
KNOWN_OPTIONS = {
    "dedup": {"window", "hash", "key", "drop_stale", "stale_after", "max_entries"},
    "linkswitch": {"switch_after", "loss_window", "max_loss", "switch_margin", "priority",
                   "hold_down", "failback_after"},
    "stats": {"interval", "csv", "log"},
}
# Errors of a key tested in another file, as (file, test function): counted as covered when
# that test exists. (This file has key_file cases too; those are the contents and modes.)
ELSEWHERE = {
    ("signing", "key_file"): ("test_signing.py", "test_bad_key_file_is_a_config_error"),
}


def loader_keys(source: str) -> dict[str, set[str]]:
    """{section: keys} from the loader's source: each `Parser::parse*` function is a section
    (parse -> top, parse_endpoint -> endpoint, ...), and its keys are the strings of its
    `std::set<std::string_view>` literals, `view.find("k")`, `required_scalar(view, m, "k"`
    and `e.name == "k"`. A new `parse_x` function with keys is a new section."""
    parts = re.split(r"^\S[^\n]*?\bParser::(\w+)\(", source, flags=re.M)
    sections: dict[str, set[str]] = {}
    for func, body in zip(parts[1::2], parts[2::2]):
        found = set()
        for lit in re.findall(r"std::set<std::string_view>\s+\w+\s*=\s*\{([^}]*)\}", body):
            found |= set(re.findall(r'"([^"]*)"', lit))
        found |= set(re.findall(r'view\.find\("([^"]*)"\)', body))
        found |= set(re.findall(r'required_scalar\(view,\s*[\w.]+,\s*"([^"]*)"', body))
        found |= set(re.findall(r'\be\.name == "([^"]*)"', body))
        if found:
            section = "top" if func == "parse" else func.removeprefix("parse_")
            # parse_endpoint_type reads an endpoint's type and mode
            section = "endpoint" if section.startswith("endpoint") else section
            sections.setdefault(section, set()).update(found)
    assert not re.search(r'view\.find\("', parts[0]), "keys read outside Parser:: functions"
    # An endpoint type's own keys are in its table (src/endpoints), which the loader reads.
    for src in sorted((REPO / "src" / "endpoints").glob("*.[ch]*")):
        sections["endpoint"] |= set(re.findall(r'\{\s*"(\w+)",\s*OptionKind::', src.read_text()))
    return sections


def plugin_options(root: Path) -> dict[str, set[str]]:
    """{plugin: option keys} from each plugin's `kOptions[]` table."""
    options = {}
    for src in sorted(root.glob("plugins/*/*.cpp")):
        if src.stem.endswith("_test"):
            continue
        m = re.search(r"kOptions\[\]\s*=\s*\{(.*?)\n\};", src.read_text(), re.S)
        if m:
            options.setdefault(src.parent.name, set()).update(
                re.findall(r'^\s*\{"(\w+)"', m.group(1), re.M))
    return options


def test_cases_cover_every_key():
    """Every key the loader takes (per section: top level, endpoint, signing, bond, filter
    entry, metrics, identity, link_events, tx_classes) and every option of the three plugins
    has a case. A case id is words joined by '-'; it covers a key when one word is the key
    and, for a key several sections share (name, bonds, endpoints), another is the section's
    name."""
    sections = loader_keys(LOADER.read_text())
    options = plugin_options(REPO)
    print(f"\nfrom the sources: {sum(map(len, sections.values()))} keys in "
          f"{len(sections)} sections {sorted(sections)}, "
          f"{sum(map(len, options.values()))} plugin options")
    for name, derived, known in (("loader", sections, KNOWN_KEYS),
                                 ("plugins", options, KNOWN_OPTIONS)):
        lost = {s: sorted(k - derived.get(s, set())) for s, k in known.items()
                if k - derived.get(s, set())}
        assert not lost, f"reading keys from the {name} sources missed {lost}: fix the regexes"
        odd = sorted(k for keys in derived.values() for k in keys
                     if not re.fullmatch(r"[a-z][a-z0-9_]*", k))
        assert not odd, f"not key names: {odd}"

    words = [set(c[0].split("-")) for c in CASES]
    shared = {k for k in set().union(*sections.values())
              if sum(k in keys for keys in sections.values()) > 1}
    missing = []
    for section, keys in sorted(sections.items()):
        for key in sorted(keys):
            if (section, key) in ELSEWHERE:
                file, func = ELSEWHERE[(section, key)]
                assert f"def {func}(" in (Path(__file__).parent / file).read_text(), \
                    f"{file}::{func} (named as covering {section}.{key}) is gone"
                continue
            need_section = key in shared and section != "top"
            if not any(key in w and (not need_section or section in w) for w in words):
                missing.append(f"{section}.{key}")
    for plugin, keys in sorted(options.items()):
        missing += [f"{plugin}.{k}" for k in sorted(keys)
                    if not any(k in w and plugin in w for w in words)]
    print(f"{len(CASES)} cases, each run with --check-config and as a normal start")
    assert not missing, f"no case for {missing}"
    assert len({c[0] for c in CASES}) == len(CASES), "case ids are unique"
    assert len(CASES) >= 150


@pytest.mark.parametrize("text,words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
@pytest.mark.parametrize("check", [True, False], ids=["check-config", "start"])
def test_config_error(mavbond_bin, plugin_dir, tmp_path, text, words, check):
    body, line, column = locate(text)
    path = tmp_path / "bad.yaml"
    path.write_text(body)
    for name, (content, mode) in KEY_FILES.items():
        (tmp_path / name).write_text(content)
        os.chmod(tmp_path / name, mode)
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
