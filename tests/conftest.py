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
