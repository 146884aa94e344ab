"""Test configuration: make ``liefi`` and ``tests/strategies.py`` importable.

The number of hypothesis examples per property test is set in
``tests/strategies.py`` (environment variable ``LIEFI_MAX_EXAMPLES``, default 25).
"""

import os
import signal
import sys

import pytest

_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (_ROOT, os.path.join(_ROOT, "tests")):
    if _p not in sys.path:
        sys.path.insert(0, _p)


def pytest_configure(config):
    """Python's own ``SIGINT`` handler, even when the suite was started with ``SIGINT`` ignored.

    A shell without job control starts a background job (``python -m pytest &``, a CI step or a launcher
    that runs the suite so) with ``SIGINT`` ignored, and Python then keeps it ignored: the tests of Ctrl-C
    that send ``SIGINT`` to this process, or to the ``liefi`` commands they start (which inherit the ignored
    disposition), saw nothing arrive: six of the default suite failed, one of them after waiting out its
    120 s timeout (``tests/test_suite_isolation.py``).  With a
    handler installed here, the commands the tests start get the default disposition (``exec`` resets a
    handled signal), as they would from a terminal.  ``SIGTERM`` likewise."""
    if hasattr(signal, "SIGINT") and signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "SIGTERM") and signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def slow_node_ids(path=os.path.join(_ROOT, "tests", "slow_tests.txt")):
    """The node ids listed in ``tests/slow_tests.txt`` (the suite's long cases, measured)."""
    with open(path, encoding="utf-8") as f:
        return {line.split("#", 1)[0].strip() for line in f} - {""}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """``@pytest.mark.slow`` tests, and those listed in ``tests/slow_tests.txt``, run only when
    asked for with ``-m slow`` (as ``pyproject.toml`` says)."""
    listed = slow_node_ids()
    for item in items:
        if item.nodeid in listed:
            item.add_marker(pytest.mark.slow)
    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="slow: run with -m slow")
    for item in items:
        if item.get_closest_marker("slow"):
            item.add_marker(skip)
