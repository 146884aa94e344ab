"""Test configuration: make ``liefi`` and ``tests/strategies.py`` importable, and a hypothesis profile.

``HYPOTHESIS_PROFILE=thorough`` runs every property test on 10x more examples.
"""

import os
import sys

from hypothesis import settings

_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
for _p in (_ROOT, os.path.join(_ROOT, "tests")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

settings.register_profile("thorough", max_examples=250, deadline=None)
if os.environ.get("HYPOTHESIS_PROFILE"):
    settings.load_profile(os.environ["HYPOTHESIS_PROFILE"])
