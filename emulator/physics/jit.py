"""The optional compiled path of the servo tick loop: numba when installed, plain Python otherwise.

The tick arithmetic is written once, as plain functions of floats, ints and bools. With numba
importable (``pip install swerve[fast]``) and ``SWERVE_NO_JIT`` unset or empty, :func:`compiled`
turns the loop into a ``numba.njit`` kernel (no ``fastmath``: the same IEEE operations in the same
order, so the same bits as the Python function) and :func:`jitable` lets that kernel call the
helpers, which stay ordinary Python functions for every other caller. Without numba both are the
identity and :data:`ENABLED` is False.

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
import os
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

try:
    if os.environ.get("SWERVE_NO_JIT"):
        raise ImportError("SWERVE_NO_JIT is set")
    os.environ["NUMBA_CACHE_DIR"] = str(CACHE_DIR)      # read by numba at import and at each compile
    import numba
    from numba.extending import register_jitable
except ImportError:
    numba = None

#: True when :func:`compiled` compiles (numba importable and ``SWERVE_NO_JIT`` unset or empty).
ENABLED = numba is not None


def jitable(fn: Callable) -> Callable:
    """``fn`` unchanged for Python callers, and callable from a :func:`compiled` kernel."""
    return register_jitable(fn) if ENABLED else fn


def compiled(fn: Callable, depends: tuple[str, ...] = ()) -> Callable | None:
    """``fn`` compiled with ``numba.njit(cache=True)`` (compiled at its first call, or loaded
    from :data:`CACHE_DIR`), or ``None`` without numba. ``depends``: source files of the
    :func:`jitable` helpers ``fn`` calls; they must lie in this package, whose files name the
    cache folder."""
    outside = [p for p in depends if Path(p).resolve().parent != PACKAGE_DIR]
    if outside:
        raise ValueError(f"{fn.__name__}: helpers outside {PACKAGE_DIR} would not enter the kernel "
                         f"cache's key: {', '.join(map(str, outside))}")
    if not ENABLED:
        return None
    try:
        return numba.njit(cache=True)(fn)
    except RuntimeError as exc:     # no writable cache directory: compiling at every start would cost seconds
        warnings.warn(f"{exc}; set NUMBA_CACHE_DIR to a writable directory. Running {fn.__name__} as Python.",
                      RuntimeWarning, stacklevel=2)
        return None
