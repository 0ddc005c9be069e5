"""Where numba caches the compiled kernels, and one status line while they compile.

:func:`prepare` runs before the package first imports numba (the compiled-kernel
modules call it).  It leaves a ``NUMBA_CACHE_DIR`` the user set alone; otherwise
numba caches next to the modules when that folder is writable, and if it is not
(a read-only install) :func:`prepare` points ``NUMBA_CACHE_DIR`` at the user's
cache folder, then at a temporary folder (one warning: the cache may not last),
and, with no writable folder at all, turns saving off (one warning: every
process compiles again).  It also prints one line on stderr the first time in a
process that one of the package's kernels is compiled rather than loaded, since
compiling takes far longer than loading (``olsbayes compile`` does it ahead of
time; :func:`olsbayes._notice.notice`, which the command line's ``--quiet``
silences), and one more when a later call starts compiling again
(:func:`say_compiling`).

numba stamps a cached kernel with the source of its own module only, yet the
machine code holds every kernel it calls from other modules: after an edit or an
upgrade that changed a called kernel's module alone, the caller would load stale
code.  :func:`prepare` therefore stamps the cache entries of the package's kernels
with all their modules' sources (:func:`kernels_stamp`): any change to one compiles
them all again.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

from ._notice import notice
from .errors import OlsBayesWarning

__all__ = ["prepare", "cache_location", "announced", "say_compiling", "kernels_stamp",
           "AGAIN_AFTER", "BURST_GAP"]

_PACKAGE = Path(__file__).resolve().parent
_KERNELS = _PACKAGE / "ml" / "_numba"
_STATE: dict[str, object] = {}  # what prepare() decided, once per process

#: Seconds after a compile line before a new burst of compiling says so again.
AGAIN_AFTER = 10.0
#: Seconds between one compile's end and the next's start that begin a new burst.
BURST_GAP = 0.1


def _writable(folder: Path) -> bool:
    """Whether files can be created in ``folder`` (made if missing)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _user_cache() -> Path:
    """The per-user cache folder of the package's compiled kernels."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "olsbayes" / "numba"


def _temporary() -> Path | None:
    """A per-user folder under the system's temporary folder, or None if there is none."""
    try:
        base = Path(tempfile.gettempdir())
    except (OSError, FileNotFoundError):
        return None
    return base / f"olsbayes-numba-{os.getuid() if hasattr(os, 'getuid') else 'user'}"


def _choose() -> tuple[str, str | None]:
    """(how the kernels are cached, folder or None); sets numba's variables if needed."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        return "NUMBA_CACHE_DIR", given
    here = _KERNELS / "__pycache__"
    if _writable(here):
        return "next to the modules", str(here)
    if any(here.glob("*.nbi")):  # a read-only install whose kernels were compiled at install
        os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = f"{__name__}.NoSaveLocator"
        return "prebuilt, read-only", str(here)
    try:
        user = _user_cache()
    except RuntimeError:  # no home folder
        user = None
    for how, folder in (("user cache", user), ("temporary", _temporary())):
        if folder is not None and _writable(folder):
            os.environ["NUMBA_CACHE_DIR"] = str(folder)
            return how, str(folder)
    os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] = f"{__name__}.NoSaveLocator"
    return "none", None


def prepare() -> None:
    """Choose numba's cache folder and register the compile notice (once per process).

    Must run before numba is imported for the cache folder to take effect.
    """
    if _STATE:
        return
    how, folder = _choose()
    _STATE.update(how=how, folder=folder, said=False, again=True, said_at=-math.inf,
                  ended=-math.inf)
    if how == "temporary":
        warnings.warn(f"the compiled kernels are cached in the temporary folder {folder} (the "
                      "package's folder and the user cache are not writable); set "
                      "NUMBA_CACHE_DIR to a lasting folder to keep them", OlsBayesWarning,
                      stacklevel=2)
    elif how == "none":
        warnings.warn("no writable folder for the compiled kernels' cache: every process "
                      "compiles them again (set NUMBA_CACHE_DIR to a writable folder)",
                      OlsBayesWarning, stacklevel=2)
    if "numba" in sys.modules:  # imported already (by another library): re-read the variables
        from numba.core import config

        config.reload_config()
    from numba.core import event

    _stamp_package_kernels()

    saving = how not in ("none", "prebuilt, read-only")

    class CompileNotice(event.Listener):
        """A stderr line when package kernels start compiling (not loading)."""

        def on_start(self, ev) -> None:
            dispatcher = ev.data["dispatcher"]
            # another library's function may have no module (built by exec): not ours
            module = getattr(getattr(dispatcher, "py_func", None), "__module__", None)
            if not isinstance(module, str) or not module.startswith("olsbayes."):
                return
            if not saving:  # nowhere to write the machine code
                dispatcher._cache.disable()
            say_compiling(time.monotonic())

        def on_end(self, ev) -> None:
            _STATE["ended"] = time.monotonic()

    event.register("numba:compile", CompileNotice())


def say_compiling(now: float) -> None:
    """The compile notice, as a package kernel starts compiling at ``now`` (monotonic s).

    The first compile of a process prints one line.  Later ones print one more
    ("compiling more ...") when they start a new burst of compiling -- more than
    :data:`BURST_GAP` s after the last compile ended -- at least :data:`AGAIN_AFTER` s
    after the last line: the first line may be far up the screen by then, and the call
    now compiling would otherwise run for seconds without a word.  None after
    :func:`announced`.
    """
    if not _STATE["said"]:
        notice("compiling numerical kernels for their first use on this machine "
               "(once; `olsbayes compile` does it ahead of time) ...")
    elif (_STATE["again"] and now - _STATE["said_at"] > AGAIN_AFTER
          and now - _STATE["ended"] > BURST_GAP):
        notice("compiling more numerical kernels for their first use ...")
    else:
        return
    _STATE.update(said=True, said_at=now)


def announced() -> None:
    """Say no more about compiling in this process (the caller has said it)."""
    prepare()
    _STATE.update(said=True, again=False)


def cache_location() -> tuple[str, str | None]:
    """How the compiled kernels are cached and where: (how, folder or None)."""
    prepare()
    return str(_STATE["how"]), _STATE["folder"]  # type: ignore[return-value]


def _no_save_locator():
    """numba's in-tree cache locator, usable where the folder is read-only (never saves).

    It finds kernels compiled into the package's folder at install time; saving is
    turned off by the compile notice.
    """
    from numba.core import caching

    base = getattr(caching, "InTreeCacheLocator", None) or caching._InTreeCacheLocator

    class NoSaveLocator(_stamped(base)):
        def ensure_cache_path(self):  # read-only: nothing to make
            pass

        @classmethod
        def from_function(cls, py_func, py_file):
            return cls(py_func, py_file) if os.path.exists(py_file) else None

    return NoSaveLocator


@functools.lru_cache(maxsize=1)
def kernels_stamp() -> str:
    """sha256 over the sources of the package's modules with cached kernels (hex).

    Read once per process, when the first kernel loads or compiles.
    """
    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if path != Path(__file__).resolve() and b"@numba.njit(cache=" in text:
            digest.update(path.relative_to(_PACKAGE).as_posix().encode() + b"\0" + text)
    return digest.hexdigest()


def _ours(py_file: object) -> bool:
    """Whether a source file belongs to the package."""
    try:
        return Path(str(py_file)).resolve().is_relative_to(_PACKAGE)
    except (OSError, ValueError):
        return False


def _stamped(base: type) -> type:
    """numba's cache locator ``base``, stamping the package's kernels with all their sources."""

    class Stamped(base):
        def get_source_stamp(self):
            own = super().get_source_stamp()
            if not _ours(getattr(self, "_py_file", None)):
                return own  # another library's function: numba's own stamp
            return own, kernels_stamp()

    Stamped.__name__ = Stamped.__qualname__ = f"Stamped{base.__name__}"
    return Stamped


def _stamp_package_kernels() -> None:
    """Stamp the package's cache entries with all kernel sources (numba's locators, wrapped).

    In this process only: the locators numba tries for a function are replaced by
    wrapped ones, which differ from numba's only for the package's files.  The
    locators of a read-only install (``NUMBA_CACHE_LOCATOR_CLASSES``) are stamped
    already; one the user named is left alone.
    """
    if os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES"):
        return
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if not isinstance(classes, list):  # another numba layout: numba's own stamps
        return
    impl._locator_classes = [c if c.__name__.startswith("Stamped") else _stamped(c)
                             for c in classes]


def __getattr__(name: str):
    if name == "NoSaveLocator":  # imported by numba by name, only when caching is off
        return _no_save_locator()
    raise AttributeError(name)
