"""Starting the emulator's child interpreter, also ahead of the command that will use it.

:func:`prestarted` spawns the child (a fresh interpreter running :data:`_CHILD_PROGRAM`, never a
fork) before a command's own imports, so the two processes import on the two CPUs at once;
:class:`swerve.emulator.process.EmulatorProcess` takes it (:func:`take_prestarted`) or spawns
one (:func:`spawn_child`). This module imports only what the spawn needs (no configs, no
driver, no :mod:`multiprocessing`): ``tools/cli.py`` imports it before the child starts.
"""
from __future__ import annotations

import contextlib
import mmap
import socket
import subprocess
import sys
import tempfile
import threading

from swerve.emulator.channel import SHARED_STATE, Channel

#: The child's program. The emulator uses no SciPy, and an import of ``scipy`` in it fails:
#: numba, loading the cached kernels, then skips its BLAS check (``numba.np.linalg.ensure_blas``
#: imports ``scipy.linalg``, ~0.4 s), which only numba's ``np.dot``/``np.linalg`` need, and the
#: kernels call neither (a ``None`` entry in ``sys.modules`` makes that import raise). The
#: cyclic garbage collector is off until the emulator is built (:func:`child.child_main`
#: then freezes what start-up made and turns it on): start-up allocates much and frees little,
#: and the collections it would trigger cost ~0.2 s of CPU. SIGINT and SIGHUP are ignored from
#: the first line: the parent decides when the child stops, also while it imports. It ends
#: without the interpreter's finalisation (:func:`child.serve_and_exit`).
_CHILD_PROGRAM = ("import gc, signal, sys; gc.disable(); sys.modules['scipy'] = None; "
                  "[signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGHUP)]; "
                  "from swerve.emulator.child import serve_and_exit; "
                  "serve_and_exit(int(sys.argv[1]), int(sys.argv[2]))")


def spawn_child() -> tuple[subprocess.Popen, Channel, mmap.mmap]:
    """A new child interpreter running :data:`_CHILD_PROGRAM`: ``(process, connection, shared
    block)``. It imports the emulator, then waits for its start request on the connection."""
    with tempfile.TemporaryFile() as block:
        block.write(bytes(SHARED_STATE.size))
        block.flush()
        shared = mmap.mmap(block.fileno(), SHARED_STATE.size)
        parent, child = socket.socketpair()
        try:
            proc = subprocess.Popen([sys.executable, "-c", _CHILD_PROGRAM, str(child.fileno()), str(block.fileno())],
                                    pass_fds=(child.fileno(), block.fileno()), stdin=subprocess.DEVNULL)
        except BaseException:
            parent.close()
            shared.close()
            raise
        finally:
            child.close()
    return proc, Channel(parent), shared


#: The child :func:`prestarted` started and no :class:`~swerve.emulator.process.EmulatorProcess` took yet.
_prestarted: tuple[subprocess.Popen, Channel, mmap.mmap] | None = None
_prestarted_lock = threading.Lock()


def take_prestarted() -> tuple[subprocess.Popen, Channel, mmap.mmap] | None:
    """The :func:`prestarted` child, once (None if there is none or it was taken)."""
    global _prestarted
    with _prestarted_lock:
        taken, _prestarted = _prestarted, None
    return taken


@contextlib.contextmanager
def prestarted():
    """Start an emulator child now, for the first :meth:`~swerve.emulator.process.EmulatorProcess.launch` inside the block.

    A fresh interpreter (never a fork) takes ~0.5 s to import the emulator and its physics; a
    command that will emulate starts it before its own imports and set-up, which then run on
    the other CPU. The child waits for its start request, so the emulator is built from the
    request exactly as without this. A child no launch took is stopped when the block ends.
    """
    global _prestarted
    with _prestarted_lock:
        if _prestarted is None:
            try:
                _prestarted = spawn_child()
            except OSError:         # only a head start: launch() spawns again and reports the error
                pass
    try:
        yield
    finally:
        spare = take_prestarted()
        if spare is not None:
            proc, conn, shared = spare
            conn.close()
            proc.terminate()         # it has started nothing yet: no pty, no thread
            proc.wait()
            shared.close()
