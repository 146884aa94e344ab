"""Progress on stderr for long work: one implementation for runs, sweeps, reproduce and maps.

``tqdm`` draws the bar when it is installed (the ``liefi[progress]`` extra); without
it one line is rewritten in place at most once a second.  Progress is shown only
when stderr is a terminal, unless forced with ``enabled=True``: output redirected
to a file (``liefi run --json > out.json``, CI logs) stays quiet.
"""

from __future__ import annotations

import sys
import time


def stderr_is_terminal():
    """Whether stderr is an interactive terminal (progress is shown only there by default)."""
    return sys.stderr is not None and hasattr(sys.stderr, "isatty") and sys.stderr.isatty()


class Progress:
    """A progress display over ``total`` units of work.

    Parameters
    ----------
    total : int
    desc : str
        What is being done (``"liefi rk4"``, ``"sweep suslov"``).
    enabled : bool or None
        ``None``: shown when stderr is a terminal and there is more than one unit.
    unit : str
        The unit counted (``"step"``, ``"task"``, ``"run"``).
    """

    def __init__(self, total, desc, enabled=None, unit="step"):
        if enabled is None:
            enabled = total > 1 and stderr_is_terminal()
        self.total, self.desc, self.unit, self.enabled = int(total), desc, unit, bool(enabled)
        self.done, self.failed, self.bar, self._last = 0, 0, None, 0.0
        if not self.enabled:
            return
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, desc=desc, unit=unit, unit_scale=unit == "step", leave=False,
                            file=sys.stderr)
        except ImportError:
            pass

    def update(self, n=1, *, failed=False):
        """``n`` more units done (``failed``: one of them failed, counted in the line)."""
        self.done += n
        self.failed += bool(failed)
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(n)
            if failed:
                self.bar.set_postfix(failed=self.failed)
        elif time.monotonic() - self._last > 1.0 or self.done >= self.total:
            self._last = time.monotonic()
            fail = f", {self.failed} failed" if self.failed else ""
            pct = 100 * self.done / max(self.total, 1)
            sys.stderr.write(f"\r{self.desc}: {self.done}/{self.total} {self.unit}s ({pct:.0f} %){fail}")
            sys.stderr.flush()

    def close(self):
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.close()
        elif self.done:
            sys.stderr.write("\n")
            sys.stderr.flush()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
