"""The emulated robot in a child process, as a separate device is on the robot.

``swerve run --emulate`` and ``swerve demo`` drive the emulator through its pty exactly as
they drive a U2D2; running the emulator (its physics clock and bus thread) in its own
process keeps it from competing with the control loop for one interpreter lock, so the loop's
timing is the loop's own. The true pose, which never crosses the bus, comes back through a small
shared-memory block ``[sim_time_s, x_m, y_m, theta_rad]``, written by an observer of the child's
emulator after every run of physics steps (at least every millisecond of wall time while the
clock runs). The child parses the robot file and the physics config, once each. With
``timing=Lockstep()`` the child's emulator owns robot time; :attr:`EmulatorProcess.control_path` is
its control socket (read the pose through it, since shared memory is not synchronised with the
bytes on the pty).

::

    with EmulatorProcess("configs/robot.yaml", timing=WallTime(5)) as emu:
        bus = Bus(emu.port, 1_000_000)
        ...
        t_sim, (x, y, theta) = emu.sim_time_s, emu.pose
    print(emu.final_stats)      # bus and clock counters, sent back when the child stops
"""
from __future__ import annotations

import mmap
import os
import subprocess

from swerve.configs import locate_robot_file, shipped
from swerve.driver.errors import ConfigError, SwerveError
from swerve.emulator.channel import SHARED_STATE, Channel
from swerve.emulator.spawn import spawn_child, take_prestarted

_START_TIMEOUT_S = 60.0
#: How long :meth:`EmulatorProcess.close` waits for the child to exit after "stop", then after SIGTERM, s.
_EXIT_TIMEOUT_S = 5.0
class EmulatorProcess:
    """:func:`swerve.emulator.factory.build_emulator` with the robot body, in a child process.

    ``robot_config`` is a path (default: :func:`swerve.configs.locate_robot_file`);
    ``emulator_config`` a path (default the shipped ``emulator.yaml``); the other keyword
    parameters are those of ``build_emulator`` (``timing``, ``faults``, ``noise``,
    ``body``, ...; default body :class:`~swerve.emulator.body_settings.BodySettings`). Attributes once started: :attr:`port` (the pty
    path), :attr:`pose` and :attr:`sim_time_s` (true state, shared memory), :attr:`pid`;
    after :meth:`close`, :attr:`final_stats`.

    :meth:`launch` starts the child and returns at once (its interpreter and the physics then
    load while the caller works on); :meth:`start` (or ``with``) launches if needed and waits
    until the child serves its pty. :meth:`close` stops the child and waits for it to exit, so
    no process is left behind.
    """

    def __init__(self, robot_config: str | os.PathLike | None = None,
                 emulator_config: str | os.PathLike | None = None, **kwargs):
        self._robot = str(locate_robot_file(robot_config).path)
        self._emulator_config = str(emulator_config or shipped("emulator.yaml"))
        self._kwargs = kwargs
        self._shared: mmap.mmap | None = None
        self._proc: subprocess.Popen | None = None
        self._conn: Channel | None = None
        self.port: str | None = None
        #: The lockstep control socket (``timing=Lockstep()``), else None.
        self.control_path: str | None = None
        self.final_stats: dict | None = None

    def launch(self) -> "EmulatorProcess":
        """Start the child process without waiting for it to serve (idempotent); a child
        :func:`swerve.emulator.spawn.prestarted` for this process is taken instead of starting one."""
        if self._proc is not None:
            return self
        self._proc, self._conn, self._shared = take_prestarted() or spawn_child()
        try:
            self._conn.send((self._robot, self._emulator_config, self._kwargs))
        except OSError:             # a child started ahead died while it imported
            self.close()
            raise SwerveError("the emulator process died while starting") from None
        return self

    def start(self) -> "EmulatorProcess":
        """:meth:`launch` if not yet, then wait until the child serves its pty (raises on failure)."""
        self.launch()
        if self.port is not None:
            return self
        parent = self._conn
        if not parent.poll(_START_TIMEOUT_S):
            self.close()
            raise SwerveError(f"the emulator process did not start within {_START_TIMEOUT_S:.0f} s")
        try:
            kind, value = parent.recv()
        except EOFError:
            self.close()
            raise SwerveError("the emulator process died while starting") from None
        if kind == "error":
            self.close()
            raise ConfigError(f"emulator: {value}")
        self.port, self.control_path = value
        return self

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    @property
    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)`` after the emulator's latest physics steps."""
        _, x, y, theta = SHARED_STATE.unpack_from(self._shared)
        return x, y, theta

    @property
    def sim_time_s(self) -> float:
        """Simulated seconds of the emulator's clock at the last pose update."""
        return SHARED_STATE.unpack_from(self._shared)[0]

    def fault(self, method: str, *args) -> None:
        """Call ``emu.faults.<method>(*args)`` in the child, e.g. ``fault("vanish", 3)``."""
        if self._conn is None:
            raise SwerveError("the emulator process is not running")
        self._conn.send(("fault", method, args))
        if not self._conn.poll(10.0):
            raise SwerveError(f"the emulator process did not answer fault {method}{args}")
        kind, value = self._conn.recv()
        if kind == "error":
            raise ConfigError(f"emulator fault {method}{args}: {value}")

    def close(self) -> None:
        """Stop the child (politely, then by force), collect its final counters and wait for it
        to exit."""
        if self._proc is None:
            return
        try:
            if self._conn is not None and self._proc.poll() is None:
                self._conn.send("stop")
                if self._conn.poll(10.0):
                    kind, value = self._conn.recv()
                    if kind == "stats":
                        self.final_stats = value
        except (EOFError, BrokenPipeError, OSError):
            pass
        if self._conn is not None:
            self._conn.close()          # EOF: a child still starting stops at its next receive
        try:
            self._proc.wait(timeout=_EXIT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=_EXIT_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._proc = self._conn = None

    def __enter__(self) -> "EmulatorProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
