"""Atomic file writes: a temporary file in the target folder, then a rename.

An interrupted run never leaves a half-written file that looks complete.  The
target must be a regular file or not exist yet: a symbolic link is written
through (the file it points at is replaced, the link kept), and a folder, FIFO,
device or socket is refused -- renaming onto it would replace the special file
(as root, ``/dev/stdout`` itself) instead of writing into it.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import InputError

__all__ = ["atomic_path", "write_text_atomic", "ensure_dir", "write_target"]


def _current_umask() -> int:
    mask = os.umask(0o022)  # reading the umask means setting it; restore at once
    os.umask(mask)
    return mask


#: The process umask at import, applied to files written through :func:`atomic_path`.
_UMASK = _current_umask()


def ensure_dir(path: str | os.PathLike, name: str = "output folder") -> Path:
    """Create ``path`` (and parents) and check it is writable; InputError if not."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{name} {str(p)!r} cannot be created: {exc.strerror or exc}") from None
    if not p.is_dir() or not os.access(p, os.W_OK):
        raise InputError(f"{name} {str(p)!r} is not a writable folder")
    return p


_KINDS = ((stat.S_ISDIR, "folder"), (stat.S_ISFIFO, "FIFO"), (stat.S_ISCHR, "character device"),
          (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket"))


def write_target(path: str | os.PathLike, name: str = "output file") -> tuple[Path, int | None]:
    """The regular file a write to ``path`` replaces, and its permission bits.

    Symbolic links are followed (``path`` itself stays a link); a missing file
    gives ``(path, None)``.  InputError when ``path`` is a folder, FIFO, device or
    socket, or cannot be examined (a loop of links, a file as a folder).
    """
    p = Path(path)
    try:
        st = os.stat(p)  # follows links
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise InputError(f"{name} {str(p)!r} cannot be written: {exc.strerror or exc}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = next((k for test, k in _KINDS if test(st.st_mode)), "special file")
        raise InputError(f"{name} {str(p)!r} is a {kind}; results are written to regular files "
                         "only (give a file name)")
    real = Path(os.path.realpath(p)) if p.is_symlink() else p
    return real, None if st is None else stat.S_IMODE(st.st_mode)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    Through a symbolic link, onto the file it points at; an existing file keeps its
    permission bits.  A folder or special file at ``path`` is refused
    (:func:`write_target`).

    Example
    -------
    >>> with atomic_path("out.nc") as tmp:          # doctest: +SKIP
    ...     dataset.to_netcdf(tmp)
    """
    target, mode = write_target(path)
    folder = ensure_dir(target.parent if str(target.parent) else ".")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists():  # mkstemp makes 0600 files; give the usual umask-based mode
            os.chmod(tmp_path, (0o666 & ~_UMASK) if mode is None else mode)
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
