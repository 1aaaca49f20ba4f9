"""The optional compiled path of the servo tick loop: numba when installed, plain Python otherwise.

The tick arithmetic is written once, as plain functions of floats, ints and bools. With numba
importable (``pip install swerve[fast]``) and ``SWERVE_NO_JIT`` unset or empty, :func:`compiled`
turns the loop into a ``numba.njit`` kernel (no ``fastmath``: the same IEEE operations in the same
order, so the same bits as the Python function) and :func:`jitable` lets that kernel call the
helpers, which stay ordinary Python functions for every other caller. Without numba both are the
identity and :data:`ENABLED` is False.

The compiled kernel is cached on disk (``cache=True``): in ``__pycache__`` next to the module when
that is writable, else in numba's per-user cache directory (``NUMBA_CACHE_DIR`` overrides both);
with none writable, the kernel runs as Python (with a warning) rather than compile at every start.
numba keys the cache on the kernel's own source file; :func:`compiled` adds this file (the compile
options) and the files of the helpers the kernel calls (``depends``), so editing either
recompiles the kernel.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path
from typing import Callable

try:
    if os.environ.get("SWERVE_NO_JIT"):
        raise ImportError("SWERVE_NO_JIT is set")
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
    from the cache), or ``None`` without numba. ``depends``: source files of the :func:`jitable`
    helpers ``fn`` calls, added to the cache's freshness stamp."""
    if not ENABLED:
        return None
    try:
        kernel = numba.njit(cache=True)(fn)
    except RuntimeError as exc:     # no writable cache directory: compiling at every start would cost seconds
        warnings.warn(f"{exc}; set NUMBA_CACHE_DIR to a writable directory. Running {fn.__name__} as Python.",
                      RuntimeWarning, stacklevel=2)
        return None
    cache_file = getattr(getattr(kernel, "_cache", None), "_cache_file", None)
    if cache_file is not None and hasattr(cache_file, "_source_stamp"):
        digest = hashlib.sha256()
        for path in (__file__, *depends):  # this file: the compile options
            digest.update(Path(path).read_bytes())
        cache_file._source_stamp = (cache_file._source_stamp, digest.hexdigest())
    return kernel
