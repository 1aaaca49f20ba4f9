"""The optional compiled path of the servo tick loop: numba when installed, plain Python otherwise.

The tick arithmetic is written once, as plain functions of floats, ints and bools. With numba
installed (``pip install swerve[fast]``) and ``SWERVE_NO_JIT`` unset or empty, :func:`compiled`
turns a loop into a ``numba.njit`` kernel (no ``fastmath``: the same IEEE operations in the same
order, so the same bits as the Python function) and :func:`jitable` lets kernels call the
helpers, which stay ordinary Python functions for every other caller. Without numba both are the
identity and :data:`ENABLED` is False. :mod:`.native` keeps a kernel as native code that loads
without numba.

numba is imported when a kernel is first needed (:func:`numba_module`), not with this module:
its import and its target's set-up cost ~0.4 s of CPU, which a process that loads only
:mod:`.native` kernels never pays. :data:`ENABLED` asks only whether numba is installed.

The compiled kernels are cached on disk (``cache=True``) in :data:`CACHE_DIR`, a folder named for
the SHA-256 of every source file of this package (kernels, the helpers they call, and this file
with the compile options) and of the reference model's control table (the unit constants the
kernels read as globals come from it); it is passed to numba as ``NUMBA_CACHE_DIR``, numba's
documented setting, before numba is imported. numba itself keys each kernel on its own source
file only, and keeps the values of the globals it read when it compiled (numba docs, "Notes on
Caching", cache limitations: https://numba.readthedocs.io/en/stable/developer/caching.html),
so an edit of a helper elsewhere in the package, or of that table, changes the folder and the
kernels compile anew. The folder lies under ``NUMBA_CACHE_DIR`` when the user set it, else in
``__pycache__/numba`` next to this file when that is writable (a checkout: the kernels stay
with the sources, as numba's own default keeps them), else under ``$XDG_CACHE_HOME/swerve/numba``
(``~/.cache/swerve/numba``; an installed package in a read-only place); with none writable, the
kernel runs as Python (with a warning) rather than compile at every start.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import threading
import warnings
from pathlib import Path
from typing import Callable

from swerve.core.user_cache import user_cache_dir
from swerve.driver.control_table import MODELS_DIR, REFERENCE_MODEL

#: The folder of this package: every kernel and helper lives here.
PACKAGE_DIR = Path(__file__).resolve().parent


def _sources_digest() -> str:
    """SHA-256 (hex, 16 digits) of the package's ``.py`` files and the reference model's table
    (:mod:`.units` derives the kernels' constants from it), by name and content."""
    digest = hashlib.sha256()
    for path in (*sorted(PACKAGE_DIR.glob("*.py")), MODELS_DIR / f"{REFERENCE_MODEL}.yaml"):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def _cache_dir(digest: str) -> Path:
    """Where the kernels of these sources are cached (see the module doc). A process started by
    one that imported this module inherits the folder in ``NUMBA_CACHE_DIR`` and keeps it."""
    name = f"kernels-{digest}"
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        return Path(given) if Path(given).name == name else Path(given) / name
    in_tree = PACKAGE_DIR / "__pycache__"
    if os.access(in_tree if in_tree.is_dir() else PACKAGE_DIR, os.W_OK):
        return in_tree / "numba" / name
    return user_cache_dir() / "numba" / name


#: The kernel cache folder of these sources (set as ``NUMBA_CACHE_DIR`` when numba is used).
CACHE_DIR = _cache_dir(_sources_digest())

#: True when :func:`compiled` compiles: numba is installed and ``SWERVE_NO_JIT`` is unset or empty.
ENABLED = not os.environ.get("SWERVE_NO_JIT") and importlib.util.find_spec("numba") is not None

#: The :func:`jitable` helpers, registered with numba when it is imported.
_JITABLE: list[Callable] = []
_numba = None
_numba_lock = threading.Lock()


def numba_module():
    """numba, imported on the first call (with ``NUMBA_CACHE_DIR`` set to :data:`CACHE_DIR`) and
    every :func:`jitable` helper registered with it. Only when :data:`ENABLED`."""
    global _numba
    with _numba_lock:
        if _numba is None:
            os.environ["NUMBA_CACHE_DIR"] = str(CACHE_DIR)      # read by numba at import and at each compile
            import numba
            from numba.extending import register_jitable
            for fn in _JITABLE:
                register_jitable(fn)
            _numba = numba
    return _numba


def jitable(fn: Callable) -> Callable:
    """``fn`` unchanged, and callable from a :func:`compiled` or :mod:`.native` kernel."""
    _JITABLE.append(fn)
    return fn


class Kernel:
    """``numba.njit(cache=True)`` of a function, made at the first call or :meth:`load` (compiled
    then, or loaded from :data:`CACHE_DIR`)."""

    def __init__(self, fn: Callable):
        self.py_func = fn
        self._dispatcher = None

    def load(self):
        """The numba dispatcher (compiling or loading nothing yet: numba does at its first call)."""
        if self._dispatcher is None:
            self._dispatcher = numba_module().njit(cache=True)(self.py_func)
        return self._dispatcher

    @property
    def signatures(self) -> list:
        """The argument types compiled or loaded so far (none before the first call)."""
        return [] if self._dispatcher is None else self._dispatcher.signatures

    def __call__(self, *args):
        return (self._dispatcher or self.load())(*args)


def check_depends(fn: Callable, depends: tuple[str, ...]) -> None:
    """Refuse helper sources outside this package: they would not enter :data:`CACHE_DIR`'s name."""
    outside = [p for p in depends if Path(p).resolve().parent != PACKAGE_DIR]
    if outside:
        raise ValueError(f"{fn.__name__}: helpers outside {PACKAGE_DIR} would not enter the kernel "
                         f"cache's key: {', '.join(map(str, outside))}")


def compiled(fn: Callable, depends: tuple[str, ...] = ()) -> Kernel | None:
    """``fn`` as a :class:`Kernel` (compiled with ``numba.njit(cache=True)`` when first called),
    or ``None`` without numba. ``depends``: source files of the :func:`jitable` helpers ``fn``
    calls; they must lie in this package, whose files name the cache folder. A cache folder that
    cannot be written leaves the kernel to run as Python, with a warning (compiling at every
    start would cost seconds)."""
    check_depends(fn, depends)
    return Kernel(fn) if can_compile(fn) else None


def can_compile(fn: Callable) -> bool:
    """Whether ``fn`` can be compiled: :data:`ENABLED`, and :data:`CACHE_DIR` exists or can be
    made and is writable (else a warning says ``fn`` runs as Python)."""
    if not ENABLED:
        return False
    try:
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        writable = os.access(CACHE_DIR, os.W_OK)
    except OSError:
        writable = False
    if not writable:
        warnings.warn(f"no writable kernel cache folder ({CACHE_DIR}); set NUMBA_CACHE_DIR to a writable "
                      f"directory. Running {fn.__name__} as Python.", RuntimeWarning, stacklevel=3)
    return writable
