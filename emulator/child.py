"""The emulator's child process (started by :class:`swerve.emulator.process.EmulatorProcess`).

:data:`swerve.emulator.spawn._CHILD_PROGRAM` runs :func:`child_main`: it reads the start request (robot file,
emulator config, :func:`~swerve.emulator.factory.build_emulator` keywords) from the connection,
serves the robot emulator, publishes its true pose into the shared block after every run of
physics steps, and answers fault requests until the parent says stop. Only this process loads
the physics; the parent imports :mod:`swerve.emulator.process` alone.
"""
from __future__ import annotations

import gc
import mmap
import os
import sys
import time
from typing import NoReturn

from swerve.driver.robot_config import load_robot_config
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.channel import SHARED_STATE, Channel
from swerve.emulator.factory import build_emulator
from swerve.emulator.physics.params import load_config
from swerve.emulator.server import freeze_startup_heap


def child_main(conn_fd: int, shared_fd: int) -> None:
    """Child process: read the start request from ``conn_fd``, start the robot emulator, publish
    the pose into the block mapped from ``shared_fd``, stop on request (or when the parent's end
    of the connection closes)."""
    conn = Channel.from_fd(conn_fd)
    shared = mmap.mmap(shared_fd, SHARED_STATE.size)
    try:
        robot_config, emulator_config, kwargs = conn.recv()
    except EOFError:                   # started ahead (spawn.prestarted) and not needed after all
        return

    def publish(emu) -> None:          # an observer: under the emulator's lock, from its bus thread
        x, y, theta = emu.world.pose
        SHARED_STATE.pack_into(shared, 0, emu.sim_time_s, x, y, theta)

    try:
        emu = build_emulator(load_robot_config(robot_config), load_config(emulator_config),
                             **{"body": BodySettings(), **kwargs})
        emu.observers.append(publish)
        emu.start()
    except Exception as exc:  # noqa: BLE001 - reported to the parent as text
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    freeze_startup_heap()
    gc.enable()                        # off since the first line (see spawn._CHILD_PROGRAM)
    try:
        conn.send(("port", (emu.port, emu.control.path if emu.control is not None else None)))
    except OSError:                    # the parent gave up while we started
        emu.close()
        return
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
