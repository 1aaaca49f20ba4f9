"""Every command that writes, against a symlinked, a read-only and a full target.

- **symlinked**: the output path is a symlink to a file elsewhere (mode 0640). The command writes
  through it: the link stays a link, the file it names holds the new output and keeps its mode.
- **read-only**: the output is a 0444 file, or lies on a read-only mount. The command exits 2 with
  one line naming the output, leaves the file as it was and creates nothing; a command that would
  move the robot (calibrate, tune) refuses before it starts (nothing else on stderr).
- **full**: the output lies on a full file system (a 64 KiB tmpfs filled to the last byte). The
  command exits 2 with one line naming the output and "No space left on device", and leaves no
  new file or folder behind (a run log keeps the cycles that reached the disk, by design).

The read-only mount and the full disk are real tmpfs mounts (the tests run as root); without
the right to mount, those cases are skipped. The commands run forked from one interpreter that
has imported swerve once (:mod:`tests.command_server`).
"""
from __future__ import annotations

import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from swerve.configs import shipped

from .command_server import CommandServer, Finished
from .tools.logs import synthetic


pytestmark = pytest.mark.slow      # a few dozen commands, some driving the emulated robot

HANG_GUARD_S = 300
ROBOT = Path(shipped("robot.yaml"))


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """The command server of this module's commands (without ``$SWERVE_CONFIG``)."""
    env = dict(os.environ)
    env.pop("SWERVE_CONFIG", None)
    with CommandServer(tmp_path_factory.mktemp("server"), env, tmp_path_factory.mktemp("streams")) as srv:
        yield srv


@pytest.fixture
def swerve(server):
    """``swerve(args, cwd)``: the command run in ``cwd``, its crash files in ``cwd/.state``."""
    def run(args: list[str], cwd: Path) -> Finished:
        return server.run(list(map(str, args)), HANG_GUARD_S, cwd=cwd, env={"XDG_STATE_HOME": str(cwd / ".state")})
    return run


@pytest.fixture(scope="module")
def log_dir(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("log") / "run"
    synthetic.write(path, synthetic.records(200))
    return path


#: Writing commands: name -> (argv with {out}, {log}; what {out} is: "file" | "robot" | "folder").
COMMANDS = {
    "synth": (["synth", "--trajectory", "line", "--out", "{out}", "--quiet"], "file", "g.npz"),
    "export-csv": (["export-csv", "{log}", "--out", "{out}"], "file", "run.csv"),
    "plot": (["plot", "{log}", "--out", "{out}"], "folder", "plots"),
    "calibrate": (["calibrate", "--emulate", "--lockstep", "--yes", "--write", "--config", "{out}"], "robot",
                  "robot.yaml"),
    "tune": (["tune", "--emulate", "--id", "1", "--write-config", "--config", "{out}", "--out", "{side}",
              "--no-progress"], "robot", "robot.yaml"),
    "tune-report": (["tune", "--emulate", "--id", "1", "--out", "{out}", "--no-progress"], "folder", "tune"),
    "run": (["run", "--trajectory", "line", "--emulate", "--lockstep", "--log", "{out}"], "folder", "log"),
    "demo": (["demo", "--trajectories", "line", "--out", "{out}"], "folder", "demo"),
    "emulate-status": (["emulate", "--physics", "--status-file", "{out}"], "file", "status.json"),
}
#: Commands whose successful run through a symlink is checked (the others run for minutes or,
#: like ``emulate``, until stopped; a folder output through a symlinked folder is plain OS behaviour).
SYMLINKED = ("synth", "export-csv", "calibrate", "tune")


def _argv(name: str, out: Path, log: Path, side: Path) -> list[str]:
    return [a.format(out=out, log=log, side=side) for a in COMMANDS[name][0]]


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _one_line(proc, *needles: str) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr and "internal error" not in proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def mount(tmp_path):
    """``mount(kind)``: a fresh 64 KiB tmpfs, ``"ro"`` (remounted read-only once filled by the
    caller's ``setup``) or ``"full"`` (filled to the last byte after ``setup``)."""
    mounted = []

    def make(kind: str, setup) -> Path:
        point = tmp_path / kind
        point.mkdir()
        if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(point)],
                          capture_output=True).returncode != 0:
            pytest.skip("mounting a tmpfs needs root")
        mounted.append(point)
        setup(point)
        if kind == "ro":
            subprocess.run(["mount", "-o", "remount,ro", str(point)], check=True)
        else:
            fd = os.open(point / ".filler", os.O_WRONLY | os.O_CREAT)
            try:
                while os.write(fd, b"\0" * 512):
                    pass
            except OSError:
                pass
            finally:
                os.close(fd)
        return point

    yield make
    for point in mounted:
        subprocess.run(["umount", str(point)], check=False)


def _setup(kind: str, name: str):
    def setup(point: Path) -> None:
        if kind == "robot":
            shutil.copy(ROBOT, point / name)
    return setup


def _existing_output(name: str, folder: Path, mode: int) -> Path:
    """The output file of command ``name`` in a new ``folder``, already there with ``mode``."""
    what, target_name = COMMANDS[name][1:]
    path = folder / target_name
    folder.mkdir()
    if what == "robot":
        shutil.copy(ROBOT, path)
    else:
        path.write_bytes(b"old")
    path.chmod(mode)
    return path


@pytest.mark.parametrize("name", SYMLINKED)
def test_a_symlinked_output_is_written_through(name, tmp_path, log_dir, swerve):
    target_name = COMMANDS[name][2]
    real = _existing_output(name, tmp_path / "real", 0o640)
    before = real.read_bytes()
    link = tmp_path / f"link-{target_name}"
    link.symlink_to(real)
    proc = swerve(_argv(name, link, log_dir, tmp_path / "side"), tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_bytes() != before
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    assert sorted(p.name for p in real.parent.iterdir()) == [target_name]      # no temporary left


@pytest.mark.parametrize("name", [n for n, c in COMMANDS.items() if c[1] in ("file", "robot")])
def test_a_read_only_output_file_is_refused(name, tmp_path, log_dir, swerve):
    out = _existing_output(name, tmp_path / "out", 0o444)
    before = _tree(out.parent)
    proc = swerve(_argv(name, out, log_dir, tmp_path / "side"), tmp_path)
    _one_line(proc, str(out), "read-only")
    assert _tree(out.parent) == before


@pytest.mark.parametrize("kind", ["ro", "full"])
@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_read_only_mount_or_full_disk_is_one_line_and_leaves_nothing(name, kind, mount, tmp_path, log_dir,
                                                                          swerve):
    what, target_name = COMMANDS[name][1:]
    point = mount(kind, _setup(what, target_name))
    out = point / target_name
    before = _tree(point)
    proc = swerve(_argv(name, out, log_dir, tmp_path / "side"), tmp_path)
    reason = "Read-only file system" if kind == "ro" else "No space left on device"
    line = _one_line(proc, reason)
    assert str(out) in line or str(point) in line, line
    after = _tree(point)
    if name == "run" and kind == "full":      # the log keeps what reached the disk
        assert set(after) - set(before) <= {"log", "log/log.mcap"}
    else:
        assert after == before
