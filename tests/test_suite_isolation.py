"""The suite's verdict does not depend on how it was started (``tests/conftest.py``).

* Started with ``SIGINT`` ignored -- a background job of a shell without job control
  (``python -m pytest &`` in a script, a CI step or launcher that runs it so) -- the tests
  of Ctrl-C still send a real ``SIGINT`` to the test process and to the ``liefi`` commands
  they start (before: six failed, one of them after its 120 s timeout).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: one Ctrl-C test in the test process, one in a ``liefi`` command it starts
CTRL_C_TESTS = ["tests/test_kernel_cache.py::test_interrupts_held_raises_after_the_block",
                "tests/test_trust_foreign.py::test_ctrl_c_while_liefi_imports_numpy_is_one_line_and_130"]


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_ctrl_c_tests_pass_when_the_suite_is_started_with_sigint_ignored():
    env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *CTRL_C_TESTS], cwd=ROOT,
                       env=env, preexec_fn=_ignore_sigint, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and "2 passed" in r.stdout, r.stdout[-3000:] + r.stderr[-2000:]
