"""The emulator's child process (started by :class:`swerve.emulator.process.EmulatorProcess`).

:data:`swerve.emulator.process._CHILD_PROGRAM` runs :func:`child_main`: it reads the start request (robot file,
emulator config, :func:`~swerve.emulator.factory.build_emulator` keywords) from the connection,
serves the robot emulator, publishes its true pose into the shared block after every run of
physics steps, and answers fault requests until the parent says stop. Only this process loads
the physics; the parent imports :mod:`swerve.emulator.process` alone.

On the wall clock the child serves before it loads numba: when numba's cache holds the kernels,
the emulator is built with its physics kernels as Python (:func:`swerve.emulator.physics.jit.defer_loading`),
the port goes to the parent, and only then does :func:`load_compiled_physics` import numba
(~0.3 s of CPU, while the parent synthesises its gains and builds its log) and switch the
kernels to their compiled form, between two runs of physics steps. Kernels not in the cache
(the first start after an edit of the physics) compile while the emulator is built, before it
serves, so no bus waits for a compilation. The Python and the compiled kernels compute the same bits
(``tests/emulator/test_batched_ticks.py``), so where the switch falls changes no result. In lockstep
(``timing.waits_on_physics``) the kernels load before the child serves: there the emulator's CPU
paces the loop, and numba loading beside the bus thread made the whole ``swerve run --lockstep``
~0.35 s longer than loading it first, though its first cycle came ~0.3 s sooner.
"""
from __future__ import annotations

import gc
import mmap
import os
import sys
import time
from multiprocessing.connection import Connection
from typing import NoReturn

from swerve.driver.robot_config import load_robot_config
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.factory import build_emulator
from swerve.emulator.physics import jit
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.robot import RobotPhysics
from swerve.emulator.physics.robot_world import RobotWorld
from swerve.emulator.process import SHARED_STATE
from swerve.emulator.server import Emulator, freeze_startup_heap
from swerve.emulator.timing import Timing

#: The interpreter's thread switch interval while numba imports, s (Python's default is 5 ms):
#: the bus thread, woken by a request, waits at most this long for the interpreter.
LOADING_SWITCH_INTERVAL_S = 0.0005


def load_compiled_physics(emu: Emulator, dt_s: float) -> bool:
    """Import numba and switch the physics kernels of the serving ``emu`` (steps of ``dt_s``
    s) to their compiled form (:mod:`swerve.emulator.physics.jit`); returns whether they are
    compiled now.

    numba imports while the bus thread serves, with a short switch interval so that its
    requests wait little for the interpreter. Each kernel then runs once on a spare copy of
    the robot's physics in this thread (:func:`~swerve.emulator.physics.jit.warming`): it
    loads from numba's cache (~20-30 ms; it compiles, for seconds, if the cache holds no match),
    while the bus thread goes on with the Python kernels. The switch itself happens under
    the emulator's lock, between two runs of physics steps.
    """
    interval = sys.getswitchinterval()
    sys.setswitchinterval(LOADING_SWITCH_INTERVAL_S)
    try:
        if not jit.prepare_kernels():
            return False
        if isinstance(emu.world, RobotWorld):
            physics = emu.world.physics
            spare = RobotPhysics(physics.cfg, physics.geometry)
            with jit.warming():
                for model in spare.servos.values():
                    model.prepare(dt_s)
                spare.prepare(dt_s)
    finally:
        sys.setswitchinterval(interval)
    with emu.lock:
        jit.switch_on()
    return True


def serves_before_loading(timing: Timing | None) -> bool:
    """Whether the child builds and serves the emulator with its kernels as Python and loads numba
    after (:func:`load_compiled_physics`): with numba enabled and every kernel in its cache, on a
    clock the client does not wait on (``timing`` ``None`` is the factory's wall clock). In
    lockstep the emulator's CPU paces the loop, so numba loading beside the bus thread would cost
    the loop more than it saves before the first cycle; kernels not in the cache compile before
    the child serves, so that no bus waits for a compilation."""
    return jit.ENABLED and not (timing is not None and timing.waits_on_physics) and jit.kernels_cached()


def child_main(conn_fd: int, shared_fd: int) -> None:
    """Child process: read the start request from ``conn_fd``, start the robot emulator, publish
    the pose into the block mapped from ``shared_fd``, stop on request (or when the parent's end
    of the connection closes)."""
    conn = Connection(conn_fd)
    shared = mmap.mmap(shared_fd, SHARED_STATE.size)
    try:
        robot_config, emulator_config, kwargs = conn.recv()
    except EOFError:                   # started ahead (process.prestarted) and not needed after all
        return

    def publish(emu) -> None:          # an observer: under the emulator's lock, from its bus thread
        x, y, theta = emu.world.pose
        SHARED_STATE.pack_into(shared, 0, emu.sim_time_s, x, y, theta)

    deferred = serves_before_loading(kwargs.get("timing"))
    if deferred:
        jit.defer_loading()            # served as Python first: load_compiled_physics below
    try:
        emu = build_emulator(load_robot_config(robot_config), load_config(emulator_config),
                             **{"body": BodySettings(), **kwargs})
        emu.observers.append(publish)
        emu.start()
    except Exception as exc:  # noqa: BLE001 - reported to the parent as text
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    try:
        conn.send(("port", (emu.port, emu.control.path if emu.control is not None else None)))
    except OSError:                    # the parent gave up while we started
        emu.close()
        return
    if deferred:
        load_compiled_physics(emu, 1.0 / emu.clock.rate_hz)
    freeze_startup_heap()
    gc.enable()                        # off since the first line (see process._CHILD_PROGRAM)
    cpu0 = time.process_time()         # CPU from here on: serving the bus (all threads)
    while True:                        # "stop" (or EOF: the parent died) ends the loop
        try:
            msg = conn.recv()
        except EOFError:
            break
        if msg == "stop":
            break
        try:                           # ("fault", method, args): e.g. ("fault", "vanish", (3,))
            _, method, fargs = msg
            # Faults are safe to change while the emulator runs; raise_hardware_error takes the
            # emulator's (non-reentrant) lock itself.
            emu.faults.apply(method, *fargs)
            conn.send(("ok", None))
        except Exception as exc:  # noqa: BLE001 - reported to the parent
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
    serve_cpu_s = time.process_time() - cpu0
    emu.close()
    try:
        t, pose = emu.true_state()
        conn.send(("stats", dict(bus=emu.stats.as_dict(), clock=emu.clock_stats.as_dict(),
                                 pose=list(pose), sim_time_s=t, serve_cpu_s=serve_cpu_s)))
    except (BrokenPipeError, OSError):
        pass


def serve_and_exit(conn_fd: int, shared_fd: int) -> NoReturn:
    """:func:`child_main`, then the process ends at once (``os._exit``), without the
    interpreter's finalisation: with numba loaded, tearing down its modules and objects takes
    ~0.1 s, which the parent would wait for in :meth:`EmulatorProcess.close`; nothing is left
    to do by then (the emulator is closed, its counters sent, the standard streams flushed).
    An exception of :func:`child_main` leaves through the normal exit, with its traceback."""
    child_main(conn_fd, shared_fd)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
