"""The demo's tasks, their order and what each gives back: plain data, picklable, cheap to import
(the process handing the tasks to the pool imports this, not :mod:`.runs`)."""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from swerve.configs import ConfigChoice

#: Where the demo writes the calibrated robot file, in its output folder.
CALIBRATED_FILE = "robot-calibrated.yaml"


@dataclass(frozen=True)
class DemoRow:
    """One run of the demo: trajectory ``name``, the robot file's state (``"as is"`` or
    ``"calibrated"``), the simulated metrics, the run's summary dict, its figures, gains and log."""

    name: str
    robot: str
    sim: dict
    summary: dict
    figures: list
    gains_file: Path
    log_dir: Path


@dataclass(frozen=True)
class Calibration:
    """What the demo's calibration found (``values`` of :func:`swerve.tools.calibrate.run_steps`),
    the robot file's values before it, and the calibrated file written."""

    values: dict
    before: dict
    path: Path


@dataclass(frozen=True)
class Task:
    """One job of the demo: the ``calibration``, or a ``run`` of trajectory ``name`` with the
    robot file ``robot`` (``"as is"``, or ``"calibrated"``: the file the calibration wrote),
    ``robot_s`` seconds of robot time long (what a run costs grows with it)."""

    kind: str
    name: str = ""
    robot: str = ""
    robot_s: float = 0.0


def tasks(robot_s: dict[str, float], *, calibrate: bool) -> tuple[Task, ...]:
    """The demo's tasks in the order their messages are printed: each trajectory of ``robot_s``
    (name -> its robot time, s) with the robot file as it is, then the calibration and each
    trajectory with the calibrated file."""
    first = [Task("run", n, "as is", s) for n, s in robot_s.items()]
    if not calibrate:
        return tuple(first)
    return (*first, Task("calibration"), *(Task("run", n, "calibrated", s) for n, s in robot_s.items()))


def longest_first(tasks: tuple[Task, ...], indices: Iterable[int]) -> list[int]:
    """``indices`` of ``tasks``, the longest run (robot time) first; ties keep their order."""
    return sorted(indices, key=lambda i: -tasks[i].robot_s)


@dataclass(frozen=True)
class TaskDone:
    """What a task left: the ``lines`` it printed, and its ``value`` (a :class:`DemoRow` or the
    :class:`Calibration`) or the ``error`` it raised (with the worker's ``trace``)."""

    lines: tuple[str, ...]
    value: DemoRow | Calibration | None = None
    error: Exception | None = None
    trace: str = ""


@dataclass(frozen=True)
class DemoPlan:
    """Everything a worker process needs to run the demo's task ``index`` (picklable when a
    worker is started; see :func:`swerve.tools.demo.runs.run_job`): the output folder, the robot
    file, the tasks and how the runs go (emulator physics, lockstep or wall clock, time scale,
    and the words for it)."""

    out: Path
    choice: ConfigChoice
    tasks: tuple[Task, ...]
    emulator_config: str
    lockstep: bool
    scale: float | None
    pace: str


__all__ = ["CALIBRATED_FILE", "Calibration", "DemoPlan", "DemoRow", "Task", "TaskDone", "longest_first", "tasks"]
