"""Where scenarios run: a local process pool, or Ray tasks on a local or remote cluster.

Both offer the :class:`Engine` protocol: ``submit(index)``, ``wait() -> Done`` (blocks until one
submitted scenario has finished or was lost with its worker) and ``close()``. Retries are the
caller's (:mod:`swerve.tools.campaign.runner`): an engine only reports a lost scenario.
Both run :func:`swerve.tools.campaign.scenario.run_scenario`, so a scenario's row does not
depend on the engine.
"""
from __future__ import annotations

import importlib.util

import multiprocessing as mp
import os
import signal
import socket
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from multiprocessing.connection import Connection, wait
from typing import Any, Protocol

from swerve.core.errors import ConfigError
from swerve.tools.signals import signals_as_interrupt

from .scenario import Outcome, run_scenario
from .spec import Campaign

#: How long a stopping worker may take to close its emulator before it is killed, s.
WORKER_STOP_S = 10.0
#: The one line ``--ray`` prints when Ray is not installed.
RAY_MISSING = 'Ray is not installed: pip install "swerve[cluster]" (or pip install ray)'


@dataclass(frozen=True)
class Done:
    """A submitted scenario that ended: its ``outcome`` (an :class:`Outcome` for a campaign, what
    the job returned for a :class:`PoolEngine` of another job), or ``lost`` (why its worker went away)."""

    index: int
    outcome: Outcome | Any | None = None
    lost: str | None = None


class Engine(Protocol):
    """Runs scenarios of one campaign; ``slots`` of them at a time."""

    slots: int
    name: str

    def submit(self, index: int) -> None:
        """Start scenario ``index`` (at most ``slots`` are outstanding)."""

    def wait(self) -> Done:
        """Block until one submitted scenario ends."""

    def close(self) -> None:
        """Stop every worker (outstanding scenarios are dropped, not reported)."""


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


def _ray_task(campaign: Campaign, index: int) -> Outcome:
    """One scenario in a Ray worker, at the priority a pool worker has.

    Ray starts its workers at nice 15 (below its own raylet); on a host shared with other work a
    scenario (and the emulator process it starts, which inherits the value) would then run only
    when nothing else wants the CPU. Where the process may (root, CAP_SYS_NICE) it takes back the
    default niceness, 0; elsewhere it keeps Ray's.
    """
    try:
        os.setpriority(os.PRIO_PROCESS, 0, 0)
    except PermissionError:
        pass
    return run_scenario(campaign, index)


class RayEngine:
    """Scenarios as Ray tasks (one CPU each). ``address`` ``"auto"`` starts a local Ray
    (``workers`` CPUs, default all); any other value is the address of a running cluster
    (``HOST:PORT`` of ``ray start --head``) to join. Every node must have swerve installed and
    the campaign's files at the same paths."""

    name = "ray"

    def __init__(self, campaign: Campaign, address: str, workers: int | None = None):
        try:
            import ray
        except ImportError:
            raise ConfigError(RAY_MISSING) from None
        self._ray = ray
        kw = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
        if address == "auto":
            ray.init(num_cpus=workers, **kw)
        else:
            check_reachable(address)    # ray.init retries an unreachable address for minutes
            ray.init(address=address, **kw)
        self.slots = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._task = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
        self._campaign = ray.put(campaign)
        self._pending: dict = {}

    def submit(self, index: int) -> None:
        self._pending[self._task.remote(self._campaign, index)] = index

    def wait(self) -> Done:
        ray = self._ray
        [ref], _ = ray.wait(list(self._pending), num_returns=1)
        index = self._pending.pop(ref)
        try:
            return Done(index, ray.get(ref))
        except ray.exceptions.RayError as exc:
            return Done(index, lost=f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")

    def close(self) -> None:
        for ref in self._pending:
            try:
                self._ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - a task that already ended cannot be cancelled
                pass
        self._pending.clear()
        self._ray.shutdown()


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


def require_ray() -> None:
    """Raise the one-line :data:`RAY_MISSING` error if Ray is not installed (checked before any
    output is made)."""
    if importlib.util.find_spec("ray") is None:
        raise ConfigError(RAY_MISSING)


#: How long a cluster's address may take to accept a connection before the campaign gives up, s.
RAY_CONNECT_TIMEOUT_S = 10.0


def check_reachable(address: str) -> None:
    """Raise :class:`ConfigError` unless something accepts a TCP connection at ``address``
    (``HOST:PORT`` of a Ray head, optionally ``ray://``), within :data:`RAY_CONNECT_TIMEOUT_S`."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"--ray {address!r}: expected auto or HOST:PORT of a running Ray cluster")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except OSError as exc:
        raise ConfigError(f"--ray {address}: no Ray cluster answers there ({exc.strerror or exc}); "
                          "start one with `ray start --head` or check the address") from None


def make_engine(campaign: Campaign, *, workers: int | None, ray: str | None) -> Engine:
    """The engine the options ask for: Ray with ``ray`` (``auto`` or an address), else the pool
    (``workers`` default: the CPUs this process may use)."""
    if ray is not None:
        return RayEngine(campaign, ray, workers)
    return PoolEngine(partial(run_scenario, campaign), workers or len(os.sched_getaffinity(0)))


__all__ = ["Done", "Engine", "PoolEngine", "RAY_MISSING", "RayEngine", "check_reachable", "make_engine", "require_ray", "run_queue"]
