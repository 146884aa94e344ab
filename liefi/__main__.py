"""``python -m liefi``: the ``liefi`` command (see :mod:`liefi.cli`)."""

import sys

try:
    from .cli import main
except KeyboardInterrupt:  # Ctrl-C while liefi (numpy, scipy, ...) is still being imported: one line, 130
    print("liefi: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
