"""Plugins that belong to the daemon (issue 22, item 4), against the real binary: as root,
--check-config and a start refuse plugin files another user owns (uid 65534), and a plugin
built for another ABI, before any of their code runs (the test plugins of tests/abi leave a
trace when their constructor runs); the owner of the daemon's executable counts as trusted
(a developer's build tree under sudo); --check-config says which plugins it loaded to check
their options; a build tree's daemon whose plugin_dir has no plugin names --plugin-dir."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from helpers import free_port, make_config, udp_server

NOBODY = 65534
EX_CONFIG = 78


def abi_plugins(mavbond_bin: str) -> Path:
    """tests/abi's plugins in the build the binary comes from."""
    return Path(mavbond_bin).resolve().parents[1] / "tests" / "abi"


def config(tmp_path: Path, plugin: str, plugin_dir: Path) -> Path:
    text = make_config([udp_server("gcs", free_port())], plugin_dir=str(plugin_dir))
    path = tmp_path / "mavbond.yaml"
    path.write_text(text + f"filters:\n  - {{plugin: {plugin}}}\n")
    return path


def run(binary, conf: Path, trace: Path, *args) -> subprocess.CompletedProcess:
    env = dict(os.environ, MAVBOND_ABI_TEST_RAN=str(trace))
    return subprocess.run([str(binary), "-c", str(conf), *args], capture_output=True, text=True,
                          timeout=20, env=env)


def plugin_tree(tmp_path: Path, mavbond_bin: str, plugin: str) -> Path:
    d = tmp_path / "plugins"
    d.mkdir(mode=0o755)
    shutil.copy(abi_plugins(mavbond_bin) / f"{plugin}.so", d / f"{plugin}.so")
    os.chmod(d / f"{plugin}.so", 0o644)
    return d


def test_another_abi_is_refused_without_running_it(mavbond_bin, tmp_path):
    plugins = plugin_tree(tmp_path, mavbond_bin, "abi_version")
    trace = tmp_path / "ran.txt"
    conf = config(tmp_path, "abi_version", plugins)
    for args in (["--check-config"], []):
        r = run(mavbond_bin, conf, trace, *args)
        print(f"\n{' '.join(args) or 'start'}: exit {r.returncode}: {r.stderr.strip()}")
        assert r.returncode == EX_CONFIG
        assert "abi_version.so: built for plugin ABI version" in r.stderr
    assert not trace.exists(), "the plugin's constructor ran: " + trace.read_text()


def test_check_config_says_what_it_ran(mavbond_bin, tmp_path):
    plugins = plugin_tree(tmp_path, mavbond_bin, "good_plugin")
    trace = tmp_path / "ran.txt"
    r = run(mavbond_bin, config(tmp_path, "good_plugin", plugins), trace, "--check-config")
    print(f"\n{r.stdout.strip()}")
    assert r.returncode == 0, r.stderr
    assert (f"{plugins}/good_plugin.so: checked as a file (owner, mode, machine, ABI, name), "
            "then loaded to check its options") in r.stdout
    assert r.stdout.strip().endswith("OK (1 endpoint, 0 bonds, 1 filter)")
    assert trace.read_text() == "good_plugin\n"


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give files to uid 65534")
def test_plugins_another_user_owns_never_run_as_root(mavbond_bin, tmp_path):
    trace = tmp_path / "ran.txt"
    results = {}
    # The plugin file, the plugin directory, a symlink to another user's file, a 0777 parent
    # whose plugins/ anyone could swap: each refused, nothing of the plugin run.
    cases = {}
    d = tmp_path / "file"
    d.mkdir()
    cases["file"] = plugin_tree(d, mavbond_bin, "good_plugin")
    os.chown(cases["file"] / "good_plugin.so", NOBODY, NOBODY)
    d = tmp_path / "dir"
    d.mkdir()
    cases["directory"] = plugin_tree(d, mavbond_bin, "good_plugin")
    os.chown(cases["directory"], NOBODY, NOBODY)
    d = tmp_path / "symlink"
    d.mkdir()
    (d / "theirs").mkdir()
    theirs = plugin_tree(d / "theirs", mavbond_bin, "good_plugin")
    os.chown(theirs / "good_plugin.so", NOBODY, NOBODY)
    (d / "plugins").mkdir(mode=0o755)
    (d / "plugins" / "good_plugin.so").symlink_to(theirs / "good_plugin.so")
    cases["symlink"] = d / "plugins"
    d = tmp_path / "open"
    d.mkdir()
    os.chmod(d, 0o777)
    cases["0777 parent"] = plugin_tree(d, mavbond_bin, "good_plugin")
    for what, plugins in cases.items():
        r = run(mavbond_bin, config(tmp_path, "good_plugin", plugins), trace, "--check-config")
        results[what] = (r.returncode, r.stderr.strip())
    for what, (code, err) in results.items():
        print(f"\n{what}: exit {code}: {err}")
    assert all(code == EX_CONFIG for code, _ in results.values())
    assert "is owned by uid 65534" in results["file"][1]
    assert f"directory {cases['directory']} is owned by uid 65534" in results["directory"][1]
    assert f"plugin {theirs}/good_plugin.so is owned by uid 65534" in results["symlink"][1]
    assert "may be written by others than its owner (mode 0777)" in results["0777 parent"][1]
    assert not trace.exists(), "a refused plugin ran: " + trace.read_text()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to give files to uid 65534")
def test_the_owner_of_the_executable_is_trusted(mavbond_bin, tmp_path):
    # A developer's build tree (uid 65534 here) run with sudo: the daemon's own executable and
    # its plugins have one owner, who could change the daemon itself anyway.
    tree = tmp_path / "build"
    tree.mkdir(mode=0o755)
    own_bin = tree / "mavbond"
    shutil.copy(mavbond_bin, own_bin)
    plugins = plugin_tree(tree, mavbond_bin, "good_plugin")
    for p in (tree, own_bin, plugins, plugins / "good_plugin.so"):
        os.chown(p, NOBODY, NOBODY)
    trace = tmp_path / "ran.txt"
    conf = config(tmp_path, "good_plugin", plugins)
    theirs = run(own_bin, conf, trace, "--check-config")
    root_owned = run(mavbond_bin, conf, trace, "--check-config")
    print(f"\ntheir own mavbond: exit {theirs.returncode} {theirs.stdout.strip()}"
          f"\nroot's mavbond: exit {root_owned.returncode} {root_owned.stderr.strip()}")
    assert theirs.returncode == 0, theirs.stderr
    assert root_owned.returncode == EX_CONFIG and "is owned by uid 65534" in root_owned.stderr
    assert trace.read_text() == "good_plugin\n", "only the check by their own mavbond ran it"


def test_a_build_trees_daemon_names_plugin_dir(mavbond_bin, tmp_path):
    # The examples name the installed plugin_dir; from a build tree the plugins are not there.
    missing = tmp_path / "usr-local-lib-mavbond-plugins"
    path = tmp_path / "mavbond.yaml"
    path.write_text(make_config([udp_server("gcs", free_port())], plugin_dir=str(missing)) +
                    "filters:\n  - {plugin: dedup}\n")
    r = subprocess.run([mavbond_bin, "--check-config", "-c", str(path)], capture_output=True,
                       text=True, timeout=20)
    built = Path(mavbond_bin).resolve().parents[1] / "plugins"
    print(f"\nexit {r.returncode}: {r.stderr.strip()}")
    assert r.returncode == EX_CONFIG
    assert (f"(plugin_dir is {missing}; this mavbond runs from a build tree: --plugin-dir "
            f"{built})") in r.stderr
