"""Where scenarios run: a local process pool (:mod:`.pool`), or Ray tasks on a local or remote cluster.

Both offer the :class:`~swerve.tools.campaign.pool.Engine` protocol: ``submit(index)``,
``wait() -> Done`` (blocks until one submitted scenario has finished or was lost with its
worker) and ``close()``. Retries are the
caller's (:mod:`swerve.tools.campaign.runner`): an engine only reports a lost scenario.
Both run :func:`swerve.tools.campaign.scenario.run_scenario`, so a scenario's row does not
depend on the engine.
"""
from __future__ import annotations

import importlib.util
import os
import socket
from functools import partial

from swerve.core.errors import ConfigError

from .pool import Done, Engine, PoolEngine, run_queue
from .scenario import Outcome, run_scenario
from .spec import Campaign

#: The one line ``--ray`` prints when Ray is not installed.
RAY_MISSING = 'Ray is not installed: pip install "swerve[cluster]" (or pip install ray)'


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
