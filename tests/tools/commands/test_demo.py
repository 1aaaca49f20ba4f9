"""``swerve demo`` on a pool of workers: the tasks and their order, the calibration before the
calibrated runs, messages printed in task order whatever finishes first, errors raised with the
engine closed, and Ctrl-C leaving no folder and no process behind."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swerve.core.errors import ConfigError, SwerveError
from swerve.tools.campaign.pool import Done
from swerve.tools.commands.demo import WorkerTraceback, run_tasks
from swerve.tools.demo import runs
from swerve.tools.demo.plan import Calibration, DemoPlan, Task, TaskDone, tasks
from swerve.tools.run.geometry import locate_and_load

NAMES = {"line": 40.0, "circle": 56.0}     # name -> robot time, s
CALIBRATION = Calibration({}, {}, Path("robot-calibrated.yaml"))


class ScriptedEngine:
    """An :class:`~swerve.tools.campaign.pool.Engine` in this process: the task submitted last
    finishes first, with the result ``results[index]``; it records what was submitted when."""

    name = "scripted"

    def __init__(self, slots: int, results: dict[int, TaskDone | None]):
        self.slots = slots
        self.results = results
        self.submitted: list[int] = []
        self.finished: list[int] = []
        self.running: list[int] = []
        self.closed = False

    def submit(self, index: int) -> None:
        assert len(self.running) < self.slots
        self.submitted.append(index)
        self.running.append(index)

    def wait(self) -> Done:
        index = self.running.pop()
        self.finished.append(index)
        result = self.results[index]
        return Done(index, result) if result is not None else Done(index, lost="killed")

    def close(self) -> None:
        self.closed = True


def _results(plan: tuple[Task, ...]) -> dict[int, TaskDone]:
    return {i: TaskDone((f"{t.kind} {t.name} {t.robot}".strip(),),
                        CALIBRATION if t.kind == "calibration" else f"row {i}")
            for i, t in enumerate(plan)}


def test_tasks_are_the_runs_as_is_then_the_calibration_then_the_calibrated_runs():
    assert tasks(NAMES, calibrate=True) == (
        Task("run", "line", "as is", 40.0), Task("run", "circle", "as is", 56.0), Task("calibration"),
        Task("run", "line", "calibrated", 40.0), Task("run", "circle", "calibrated", 56.0))
    assert tasks(NAMES, calibrate=False) == (Task("run", "line", "as is", 40.0), Task("run", "circle", "as is", 56.0))


def test_the_calibration_starts_first_then_the_longest_run_ready():
    """One slot: the calibration, then of the runs ready (all, once it has finished) the longest
    first, as is before calibrated on a tie; the messages still come in task order."""
    plan = tasks({"line": 40.0, "curvilinear": 140.0, "circle": 56.0}, calibrate=True)
    engine = ScriptedEngine(1, _results(plan))
    values = run_tasks(plan, engine)
    assert [plan[i] for i in engine.submitted] == [
        Task("calibration"), Task("run", "curvilinear", "as is", 140.0),
        Task("run", "curvilinear", "calibrated", 140.0), Task("run", "circle", "as is", 56.0),
        Task("run", "circle", "calibrated", 56.0), Task("run", "line", "as is", 40.0),
        Task("run", "line", "calibrated", 40.0)]
    assert values == ["row 0", "row 1", "row 2", CALIBRATION, "row 4", "row 5", "row 6"]


def test_the_longest_run_goes_first_before_the_calibration_ends():
    """Two slots, the calibration finishing last of the first two: the longest run as is is the
    other one started."""
    plan = tasks({"line": 40.0, "curvilinear": 140.0}, calibrate=True)
    engine = ScriptedEngine(2, _results(plan))
    run_tasks(plan, engine)
    assert engine.submitted[:2] == [2, 1]


@pytest.mark.parametrize("slots", [1, 2, 5])
def test_messages_and_values_come_in_task_order_and_calibrated_runs_wait_for_the_calibration(slots, capsys):
    plan = tasks(NAMES, calibrate=True)
    engine = ScriptedEngine(slots, _results(plan))
    values = run_tasks(plan, engine)
    assert values == ["row 0", "row 1", CALIBRATION, "row 3", "row 4"]
    assert capsys.readouterr().out.splitlines() == [
        "run line as is", "run circle as is", "calibration", "run line calibrated", "run circle calibrated"]
    assert engine.submitted[0] == 2                                   # the calibration first
    assert engine.finished.index(2) < min(engine.submitted.index(3), engine.submitted.index(4))
    assert sorted(engine.submitted) == list(range(len(plan))) and engine.closed


def test_an_error_is_raised_after_its_messages_with_the_workers_traceback_and_the_engine_closed(capsys):
    plan = tasks(NAMES, calibrate=True)
    results = _results(plan)
    results[2] = TaskDone(("[calibration] started",), error=ConfigError("bad robot file"), trace="Traceback ...")
    engine = ScriptedEngine(1, results)
    with pytest.raises(ConfigError, match="bad robot file") as info:
        run_tasks(plan, engine)
    assert isinstance(info.value.__cause__, WorkerTraceback) and "Traceback" in str(info.value.__cause__)
    assert capsys.readouterr().out.splitlines() == ["[calibration] started"]
    assert engine.closed and engine.submitted == [2]                  # nothing more was started


def test_a_lost_worker_is_an_error_naming_the_task():
    plan = tasks(NAMES, calibrate=False)
    results = _results(plan)
    results[1] = None
    engine = ScriptedEngine(2, results)
    with pytest.raises(SwerveError, match=r"run of circle \(robot file as is\) went away \(killed\)"):
        run_tasks(plan, engine)
    assert engine.closed


def _descendants(pid: int) -> set[int]:
    """The processes below ``pid``, from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow
def test_ctrl_c_during_the_runs_leaves_no_folder_and_no_process(tmp_path):
    """Ctrl-C (SIGINT to the process group, as a terminal sends it) while both workers run:
    exit 130, the output folder the demo made is gone, and every process it started has exited.
    The waits are hang guards only."""
    out = tmp_path / "new" / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "demo", "--trajectories", "line,circle",
                             "--no-calibrate", "--workers", "2", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while len(list((out / "logs").glob("*"))) < 2:      # both runs write their logs
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the runs did not start"
            time.sleep(0.2)
        started = _descendants(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "swerve demo: stopped by SIGINT", err
    assert not (tmp_path / "new").exists()
    deadline = time.monotonic() + 30
    while [p for p in started if _alive(p)] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert started and not [p for p in started if _alive(p)]


def test_an_error_of_the_emulated_run_or_the_calibration_comes_back_as_the_tasks_error(tmp_path, monkeypatch):
    """A task's exception is carried back in its :class:`TaskDone` (the main process raises it),
    with what the task did before it (the run's gains are synthesised before its emulator starts)."""

    def emulator(*args, **kw):
        raise SwerveError("emulator refused")

    monkeypatch.setattr(runs, "run_tracking", emulator)
    monkeypatch.setattr(runs, "_calibrate", emulator)
    choice, _ = locate_and_load(None)
    plan = DemoPlan(tmp_path, choice, tasks({"line": 40.0}, calibrate=True), "realistic", True, None, "x")
    for index in (0, 1):
        done = runs.run_job(plan, index)
        assert isinstance(done.error, SwerveError) and "emulator refused" in str(done.error)
        assert done.value is None and "emulator refused" in done.trace
    assert (tmp_path / "gains" / "line.npz").is_file()
