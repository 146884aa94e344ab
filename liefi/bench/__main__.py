"""``python -m liefi.bench``: the same as ``liefi bench``."""

from .cli import main

raise SystemExit(main())
