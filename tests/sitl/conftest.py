"""Fixtures for tests/sitl: those of tests/integration (the mavbond binary, its plugins, the
sanitizer check after every test), loaded from there under another module name."""
from __future__ import annotations

import sys
from pathlib import Path

INTEGRATION = Path(__file__).resolve().parents[1] / "integration"
sys.path.insert(0, str(INTEGRATION))
sys.path.insert(0, str(INTEGRATION.parent / "peers"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers import integration_conftest  # noqa: E402

_integration = integration_conftest()
no_sanitizer_reports = _integration.no_sanitizer_reports
mavbond_bin = _integration.mavbond_bin
plugin_dir = _integration.plugin_dir
