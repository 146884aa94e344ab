"""Writing an output file: a failure names the file and says what to do.

A full disk (``ENOSPC``), a file size limit (``EFBIG``, "File too large") or a
quota (``EDQUOT``) surface from ``write()`` or ``close()`` as an ``OSError``
with no file name.  :func:`writing` turns it into one that names the file.
"""

from __future__ import annotations

import contextlib
import errno as _errno

#: "no room": the disk, a file size limit, a quota
NO_ROOM = (_errno.ENOSPC, _errno.EFBIG, _errno.EDQUOT)


def write_error(exc, path):
    """``exc`` (an ``OSError`` met while writing ``path``) as an ``OSError`` whose message names ``path``."""
    why = exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
    if exc.errno in NO_ROOM:
        todo = "free space on its disk (or raise the file size limit) or choose another output folder (--out)"
    else:
        todo = "check that it can be written or choose another output folder (--out)"
    return WriteError(exc.errno, f"cannot write {path} ({why}); {todo}", str(path))


class WriteError(OSError):
    """An output file could not be written; ``str()`` is the whole message (``errno``, ``filename`` kept)."""

    def __str__(self):
        return self.strerror


@contextlib.contextmanager
def writing(path):
    """Within the block, an ``OSError`` is re-raised as :func:`write_error` of ``path``."""
    try:
        yield
    except OSError as exc:
        raise write_error(exc, path) from None


def probe_writable(path):
    """Prove that ``path`` can be written by opening it for writing, before any work; ``None`` if it can,
    else the reason (``"Permission denied"``, ...).

    ``os.access`` says yes to root for any path, also in ``/proc`` or on a read-only mount, where
    the write fails later.  An existing file is opened for appending (its content is untouched);
    a missing one is created exclusively and removed again.
    """
    import os

    try:
        try:
            with open(path, "xb"):
                pass
        except FileExistsError:
            with open(path, "ab"):
                return None
        os.remove(path)
    except OSError as exc:
        return exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
    return None
