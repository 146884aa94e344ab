"""Test configuration: make ``liefi`` and ``tests/strategies.py`` importable.

The number of hypothesis examples per property test is set in
``tests/strategies.py`` (environment variable ``LIEFI_MAX_EXAMPLES``, default 25).
"""

import os
import sys

_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (_ROOT, os.path.join(_ROOT, "tests")):
    if _p not in sys.path:
        sys.path.insert(0, _p)


def pytest_collection_modifyitems(config, items):
    """``@pytest.mark.slow`` tests run only when asked for with ``-m slow`` (as ``pyproject.toml`` says)."""
    import pytest

    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="slow: run with -m slow")
    for item in items:
        if item.get_closest_marker("slow"):
            item.add_marker(skip)
