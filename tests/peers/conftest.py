"""Fixtures for tests/peers: those of tests/integration (the mavbond binary, its plugins, the
`lab` that starts gateways and emulators and always stops them, the sanitizer check after
every test), loaded from there under another module name, and the peers' own skips."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

INTEGRATION = Path(__file__).resolve().parents[1] / "integration"
sys.path.insert(0, str(INTEGRATION))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers import integration_conftest  # noqa: E402

_integration = integration_conftest()

no_sanitizer_reports = _integration.no_sanitizer_reports
mavbond_bin = _integration.mavbond_bin
plugin_dir = _integration.plugin_dir
lab = _integration.lab


@pytest.fixture(scope="session")
def mavsdk_available():
    """MAVSDK's wheel bundles a C++ library built for a few platforms only; where pip could
    not install it (another architecture, an older glibc), these tests cannot run."""
    try:
        import mavsdk  # noqa: F401
        from mavsdk.cmavsdk_loader import _cmavsdk_lib  # noqa: F401
    except (ImportError, OSError) as e:
        pytest.skip(f"MAVSDK cannot run here (pip install mavsdk: {e})")
