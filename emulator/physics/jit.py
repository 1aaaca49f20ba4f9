"""The optional compiled path of the servo tick loop: numba when installed, plain Python otherwise.

The tick arithmetic is written once, as plain functions of floats, ints and bools. With numba
importable (``pip install swerve[fast]``) and ``SWERVE_NO_JIT`` unset or empty (:data:`ENABLED`),
:func:`compiled` makes each kernel a :class:`Kernel` and :func:`jitable` notes the helpers it
calls; :func:`load_kernels` then imports numba, registers the helpers and turns every kernel
into a ``numba.njit`` dispatcher (no ``fastmath``: the same IEEE operations in the same order,
so the same bits as the Python function). Until then a kernel is not :attr:`Kernel.loaded` and
its callers run the Python function: numba's import and the initialisation of its CPU target
cost ~0.3 s of CPU, which the emulator's child spends after it serves its pty
(:mod:`swerve.emulator.child`). Without numba :func:`compiled` gives ``None``, :func:`jitable`
is the identity and :data:`ENABLED` is False.

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

import contextlib
import hashlib
import importlib.util
import os
import threading
import warnings
from pathlib import Path
from typing import Callable

from swerve.driver.control_table import MODELS_DIR, REFERENCE_MODEL

#: numba, once :func:`import_numba` has imported it.
numba = None

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
    one that loaded the kernels (:func:`import_numba`) inherits the folder in ``NUMBA_CACHE_DIR``
    and keeps it."""
    name = f"kernels-{digest}"
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        return Path(given) if Path(given).name == name else Path(given) / name
    in_tree = PACKAGE_DIR / "__pycache__"
    if os.access(in_tree if in_tree.is_dir() else PACKAGE_DIR, os.W_OK):
        return in_tree / "numba" / name
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "swerve" / "numba" / name


#: The kernel cache folder of these sources (set as ``NUMBA_CACHE_DIR`` when numba is used).
CACHE_DIR = _cache_dir(_sources_digest())

#: True when :func:`compiled` gives kernels (numba installed and ``SWERVE_NO_JIT`` unset or empty).
ENABLED = not os.environ.get("SWERVE_NO_JIT") and importlib.util.find_spec("numba") is not None

#: The :func:`jitable` helpers, registered with numba by :func:`import_numba`.
_HELPERS: list[Callable] = []
#: Every :class:`Kernel` :func:`compiled` made, loaded by :func:`load_kernels`.
_KERNELS: list["Kernel"] = []
#: Whether the first :meth:`Kernel.ready` loads the kernels (False once :func:`load_kernels`
#: ran, or after :func:`defer_loading`).
_load_at_first_use = True
#: Whether numba failed to import (it is not tried again).
_numba_missing = False


class _Warming(threading.local):
    """Per thread: whether :func:`warming` lets this thread's callers run the loaded kernels."""

    on = False


_warming = _Warming()


class Kernel:
    """A tick loop that runs compiled once numba is loaded, and as Python until then.

    :meth:`ready` says which: False, callers run :attr:`python` (the same function as plain
    Python, the same bits); True, calling the kernel calls its ``numba.njit`` dispatcher
    (compiled at its first call, or loaded from :data:`CACHE_DIR`), and :attr:`signatures`
    lists the specialisations it holds. The kernels load and switch on at the first
    :meth:`ready` of any of them; after :func:`defer_loading`, :func:`prepare_kernels` loads
    them (:meth:`ready` is then True only inside :func:`warming`, in its thread) and
    :func:`switch_on` turns them on for every caller.
    """

    def __init__(self, fn: Callable):
        self.python = fn
        self._dispatcher = None
        self._on = False

    def ready(self) -> bool:
        """Whether calls run the compiled kernel (loading the kernels first unless deferred)."""
        if self._on:
            return True
        if _load_at_first_use:
            load_kernels()
            return self._on
        return self._dispatcher is not None and _warming.on

    @property
    def signatures(self) -> list:
        """The compiled specialisations loaded so far (none before the first call)."""
        return [] if self._dispatcher is None else self._dispatcher.signatures

    def __call__(self, *args):
        return self._dispatcher(*args)


def jitable(fn: Callable) -> Callable:
    """``fn`` unchanged for Python callers, and callable from a :func:`compiled` kernel once
    :func:`import_numba` has registered it."""
    if ENABLED:
        _HELPERS.append(fn)
    return fn


def compiled(fn: Callable, depends: tuple[str, ...] = ()) -> Kernel | None:
    """``fn`` as a :class:`Kernel` (compiled with ``numba.njit(cache=True)`` once loaded), or
    ``None`` without numba. ``depends``: source files of the :func:`jitable` helpers ``fn``
    calls; they must lie in this package, whose files name the cache folder."""
    outside = [p for p in depends if Path(p).resolve().parent != PACKAGE_DIR]
    if outside:
        raise ValueError(f"{fn.__name__}: helpers outside {PACKAGE_DIR} would not enter the kernel "
                         f"cache's key: {', '.join(map(str, outside))}")
    if not ENABLED:
        return None
    kernel = Kernel(fn)
    _KERNELS.append(kernel)
    return kernel


def defer_loading() -> None:
    """Keep every kernel Python until :func:`load_kernels` is called (a process that serves
    first and loads numba after, :mod:`swerve.emulator.child`)."""
    global _load_at_first_use
    _load_at_first_use = False


def kernels_cached() -> bool:
    """Whether :data:`CACHE_DIR` holds numba's index of every :func:`compiled` kernel, so that
    each loads in ~20-30 ms; without one the first call compiles (seconds). numba names an
    index ``<file stem>.<qualified name>-<line>.py<version>.nbi``."""
    return all(any(CACHE_DIR.rglob(f"{Path(k.python.__code__.co_filename).stem}.{k.python.__qualname__}-*.nbi"))
               for k in _KERNELS)


def import_numba():
    """Import numba with :data:`CACHE_DIR` as its cache, register the :func:`jitable` helpers
    and initialise its CPU target (~0.3 s of CPU, once); the kernels stay as they are. Returns
    the module, or ``None`` when it cannot be imported (the kernels then stay Python)."""
    global numba, _numba_missing
    if numba is not None or _numba_missing or not ENABLED:
        return numba
    os.environ["NUMBA_CACHE_DIR"] = str(CACHE_DIR)      # read by numba at import and at each compile
    try:
        import numba as module
        from numba.core.registry import cpu_target
        from numba.extending import register_jitable
    except ImportError as exc:
        _numba_missing = True
        warnings.warn(f"numba cannot be imported ({exc}); the physics runs as Python.", RuntimeWarning,
                      stacklevel=2)
        return None
    for fn in _HELPERS:
        register_jitable(fn)
    cpu_target.typing_context.refresh()      # the target's one-off set-up, else done by the first kernel call
    cpu_target.target_context.refresh()
    numba = module
    return numba


def prepare_kernels() -> bool:
    """Give every :func:`compiled` kernel its ``numba.njit`` dispatcher (importing numba first,
    see :func:`import_numba`), not yet on for its callers (:func:`switch_on`); each loads its
    machine code from the cache, or compiles, at its first call. Returns whether they have one
    (False without numba, or with no writable cache folder: they then stay Python, with a
    warning)."""
    global _load_at_first_use
    _load_at_first_use = False
    if import_numba() is None:
        return False
    for kernel in _KERNELS:
        if kernel._dispatcher is not None:
            continue
        try:
            kernel._dispatcher = numba.njit(cache=True)(kernel.python)
        except RuntimeError as exc:     # no writable cache directory: compiling at every start would cost seconds
            warnings.warn(f"{exc}; set NUMBA_CACHE_DIR to a writable directory. Running "
                          f"{kernel.python.__name__} as Python.", RuntimeWarning, stacklevel=2)
            return False
    return True


@contextlib.contextmanager
def warming():
    """Inside, this thread's callers run the kernels :func:`prepare_kernels` gave a dispatcher
    before they are switched on, e.g. on spare models, so their first calls (a load from the
    cache, or a compilation) happen here and not in another thread that serves a bus."""
    _warming.on = True
    try:
        yield
    finally:
        _warming.on = False


def switch_on() -> None:
    """Every kernel with a dispatcher (:func:`prepare_kernels`) runs compiled for every caller
    from now on."""
    for kernel in _KERNELS:
        kernel._on = kernel._dispatcher is not None


def load_kernels() -> bool:
    """:func:`prepare_kernels`, then :func:`switch_on`; returns whether the kernels are on."""
    loaded = prepare_kernels()
    if loaded:
        switch_on()
    return loaded
