"""A local pool of worker processes, each running jobs one index at a time.

:class:`PoolEngine` offers the :class:`Engine` protocol: ``submit(index)``, ``wait() -> Done``
(blocks until one submitted job has finished or was lost with its worker) and ``close()``; a
worker imports what its job needs once and runs every index it is given. :func:`run_queue`
keeps an engine's slots busy. This module imports no more than the pool needs, so a command
that only hands jobs out starts quickly: a :class:`ModuleJob` is imported where it runs.
"""
from __future__ import annotations

import importlib
import multiprocessing as mp
import os
import signal
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any, Protocol

from swerve.core.errors import ConfigError
from swerve.tools.signals import signals_as_interrupt

#: How long a stopping worker may take to close its emulator before it is killed, s.
WORKER_STOP_S = 10.0


@dataclass(frozen=True)
class Done:
    """A submitted job that ended: its ``outcome`` (what the job returned: a campaign's
    :class:`~swerve.tools.campaign.scenario.Outcome`, the demo's task result), or ``lost`` (why
    its worker went away)."""

    index: int
    outcome: Any | None = None
    lost: str | None = None


class Engine(Protocol):
    """Runs the jobs of one command (a campaign's scenarios, the demo's tasks), ``slots`` at a time."""

    slots: int
    name: str

    def submit(self, index: int) -> None:
        """Start job ``index`` (at most ``slots`` are outstanding)."""

    def wait(self) -> Done:
        """Block until one submitted job ends."""

    def close(self) -> None:
        """Stop every worker (outstanding jobs are dropped, not reported)."""


def _worker(conn: Connection, job: Callable[[int], Any]) -> None:
    """A pool worker: run ``job`` on each index received, send what it returns; ``None`` stops it.
    A stop signal ends the running job through its clean-up (emulator closed) and exits."""
    with signals_as_interrupt():
        try:
            while (index := conn.recv()) is not None:
                conn.send(job(index))
        except (KeyboardInterrupt, EOFError, BrokenPipeError):
            pass


class _Slot:
    def __init__(self, ctx, job: Callable[[int], Any]):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker, args=(child, job), name="swerve-worker")
        self.proc.start()
        child.close()
        self.index: int | None = None


class PoolEngine:
    """``workers`` local processes (started with ``spawn``), each running ``job(index)`` for one
    index at a time; ``job`` is picklable and must not raise (a campaign's is
    ``partial(run_scenario, campaign)``). A worker that dies mid-job (killed, crashed) is
    reported as lost and replaced."""

    name = "pool"

    def __init__(self, job: Callable[[int], Any], workers: int):
        if workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {workers}")
        self._ctx = mp.get_context("spawn")
        self._job = job
        self.slots = workers
        self._slots: list[_Slot] = []

    def submit(self, index: int) -> None:
        free = next((s for s in self._slots if s.index is None), None)
        if free is None:
            free = _Slot(self._ctx, self._job)
            self._slots.append(free)
        free.index = index
        free.conn.send(index)

    def wait(self) -> Done:
        while True:
            busy = [s for s in self._slots if s.index is not None]
            if not busy:
                raise RuntimeError("wait() with nothing submitted")
            ready = wait([s.conn for s in busy] + [s.proc.sentinel for s in busy])
            for s in busy:
                if s.conn in ready:
                    try:
                        outcome = s.conn.recv()
                    except (EOFError, OSError):
                        continue            # died while sending: its sentinel reports it
                    index, s.index = s.index, None
                    return Done(index, outcome)
            for s in busy:
                if s.proc.sentinel in ready:
                    s.proc.join()
                    self._slots.remove(s)
                    s.conn.close()
                    return Done(s.index, lost=f"worker process exited with status {s.proc.exitcode}")

    def close(self) -> None:
        for s in self._slots:
            try:
                if s.index is None:
                    s.conn.send(None)
                elif s.proc.is_alive():
                    os.kill(s.proc.pid, signal.SIGTERM)
            except (OSError, ValueError):
                pass
        for s in self._slots:
            s.proc.join(WORKER_STOP_S)
            if s.proc.is_alive():
                s.proc.kill()
                s.proc.join()
            s.conn.close()
        self._slots.clear()


@dataclass(frozen=True)
class ModuleJob:
    """The job ``run_job(data, index)`` of the module named ``module`` (dotted), imported by the
    worker that runs it: the process handing out the indices never imports that module nor what
    it imports. ``data`` is picklable."""

    module: str
    data: Any

    def __call__(self, index: int) -> Any:
        return importlib.import_module(self.module).run_job(self.data, index)


def run_queue(engine: Engine, todo: deque[int]) -> Iterator[Done]:
    """Keep ``engine``'s slots busy with the indices of ``todo`` (taken from its left end) and
    yield each :class:`Done` as it ends. Between two yields the caller may add indices to
    ``todo``; the iteration ends when ``todo`` is empty and nothing is outstanding."""
    outstanding = 0
    while todo or outstanding:
        while todo and outstanding < engine.slots:
            engine.submit(todo.popleft())
            outstanding += 1
        done = engine.wait()
        outstanding -= 1
        yield done


__all__ = ["Done", "Engine", "ModuleJob", "PoolEngine", "WORKER_STOP_S", "run_queue"]
