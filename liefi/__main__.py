"""``python -m liefi``: the ``liefi`` command (see :mod:`liefi.cli`)."""

import sys

from .cli import main

sys.exit(main())
