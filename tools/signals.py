"""SIGINT, SIGTERM and SIGHUP stop a command the same way, and never cut a safe stop short.

:func:`signals_as_interrupt` (entered once, at the ``swerve`` command's boundary) turns the first
of these signals into :class:`Interrupted`, a :class:`KeyboardInterrupt` that carries the signal
number, so every ``finally`` / ``with`` that handles Ctrl-C (wheels to zero, torque off, log
closed) handles ``kill`` and a closed terminal too. Every later signal is only counted: a second
Ctrl-C cannot interrupt the shutdown. :func:`safe_stop` marks a block (a wheel set's torque-off)
that a *first* signal must not interrupt either: the signal is held and raised when it ends.
The command exits with ``128 + signum`` (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP).
"""
from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: The signals that stop a command.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived; ``signum`` is its number, ``name`` e.g. ``"SIGTERM"``."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        super().__init__(self.name)

    @property
    def exit_code(self) -> int:
        """The shell's convention for death by a signal: 128 + its number."""
        return 128 + self.signum


class _State:
    """What the handler knows: the first signal seen, whether it was raised, the shield depth."""

    def __init__(self) -> None:
        self.first: int | None = None
        self.raised = False
        self.shield = 0
        self.count = 0


_state: _State | None = None


def _handler(signum, _frame) -> None:
    st = _state
    if st is None:                              # not installed: behave like Python's default
        raise Interrupted(signum)
    st.count += 1
    if st.first is None:
        st.first = signum
    if st.raised or st.shield:
        return                                  # counted; the stop already under way goes on
    st.raised = True
    raise Interrupted(signum)


@contextlib.contextmanager
def signals_as_interrupt(process_exit: bool = False) -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM/SIGHUP raise :class:`Interrupted` once (see module doc).

    A no-op outside the main thread (signal handlers can only be set there). The previous
    handlers are restored on exit; with ``process_exit`` (the console script, which exits right
    after the block) a stop signal that arrived leaves them ignored instead, so a second signal
    cannot replace the exit status on the way out.
    """
    global _state
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    outer = _state
    _state = _State()
    try:
        for s in STOP_SIGNALS:
            previous[s] = signal.signal(s, _handler)
        yield
    finally:
        stopping = process_exit and _state.first is not None
        for s, h in previous.items():
            signal.signal(s, signal.SIG_IGN if stopping else h)
        _state = outer


@contextlib.contextmanager
def safe_stop() -> Iterator[None]:
    """Hold stop signals while the block runs (a shutdown that must finish); raise one after.

    If a first stop signal arrived during the block, :class:`Interrupted` is raised when it
    ends (unless another exception is already on its way out).
    """
    st = _state
    if st is None:
        yield
        return
    st.shield += 1
    ok = False
    try:
        yield
        ok = True
    finally:
        st.shield -= 1
        if ok and not st.shield and st.first is not None and not st.raised:
            st.raised = True
            raise Interrupted(st.first)


class shielded_exit(contextlib.AbstractContextManager):
    """Wrap a context manager so that its ``__exit__`` (e.g. torque off) runs in :func:`safe_stop`."""

    def __init__(self, cm):
        self._cm = cm

    def __enter__(self):
        return self._cm.__enter__()

    def __exit__(self, exc_type, exc, tb):
        with safe_stop():
            return self._cm.__exit__(exc_type, exc, tb)


def hold_stop_signals() -> None:
    """From now on stop signals are only counted (the command is already stopping)."""
    if _state is not None:
        _state.raised = True


__all__ = ["Interrupted", "STOP_SIGNALS", "hold_stop_signals", "safe_stop", "shielded_exit",
           "signals_as_interrupt"]
