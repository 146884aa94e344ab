"""Writing an output file: a failure names the file and says what to do.

A full disk (``ENOSPC``), a file size limit (``EFBIG``, "File too large") or a
quota (``EDQUOT``) surface from ``write()`` or ``close()`` as an ``OSError``
with no file name.  :func:`writing` turns it into one that names the file.

An output file is written whole or not at all (:func:`replacing`): into a
temporary file next to it, renamed over it at the end (``os.replace``, one
step on a POSIX filesystem).  Ctrl-C, ``SIGTERM`` or a full disk in the middle
of a write leaves the file as it was before (or absent), never half of it -- a
truncated figure, CSV or ``.npz`` that a later command would read and trust or
crash on.
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
def replacing(path):
    """Write ``path`` whole or not at all: the block writes the yielded temporary path (in ``path``'s folder,
    ending with ``path``'s suffix, so that matplotlib and numpy choose the format from it), which then replaces
    ``path`` in one rename.  If the block fails or is interrupted (``KeyboardInterrupt``), the temporary file is
    removed and ``path`` is untouched.  An ``OSError`` names ``path`` (:func:`writing`).  The new file gets the
    usual mode (``0666`` less the umask), as ``open(path, "w")`` would.  In a folder where no new file may be
    created (but ``path`` may be written), the block writes ``path`` itself."""
    import os
    import secrets

    folder, base = os.path.split(os.path.abspath(path))
    tmp = os.path.join(folder, f".{base}.{secrets.token_hex(4)}.tmp{os.getpid()}{os.path.splitext(base)[1]}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except PermissionError:  # a file that can be written in a folder that cannot: written in place, as before
        with writing(path):
            yield path
        return
    except OSError as exc:
        raise write_error(exc, path) from None
    try:
        with writing(path):
            yield tmp
            os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def remove_temporaries(folder, pids):
    """Remove from ``folder`` the temporary files of :func:`replacing` that the processes ``pids`` (killed
    workers, which could not remove their own) left behind: ``.NAME.<token>.tmp<pid>[.suffix]``."""
    import os
    import re

    pids = {int(p) for p in pids}
    if not pids:
        return
    for name in os.listdir(folder):
        m = re.fullmatch(r"\..+\.tmp(\d+)(\.[^.]*)?", name)
        if m and int(m.group(1)) in pids:
            try:
                os.remove(os.path.join(folder, name))
            except OSError:
                pass


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
