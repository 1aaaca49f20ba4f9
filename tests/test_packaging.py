"""The wheel as a user gets it: built, installed into a fresh venv, run from an empty folder.

Builds ``swerve-*.whl`` with ``pip wheel``, installs it (and its dependencies from the package
index, through pip's cache) into a new virtual environment, and from an empty temporary folder
runs ``swerve sim``, ``swerve emulate`` + ``swerve scan`` and a short ``swerve run --emulate``:
nothing may depend on a checkout or on the working directory. The installed files must be one
package ``swerve`` with its configs inside, and no stray top-level packages.
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
#: Folder names that must not be installed as top-level packages.
STRAY = ("driver", "emulator", "controller", "tools", "configs")
#: A 12 s straight line (the paper's line, shortened, wheels already along it), run in lockstep
#: so that the verdict does not depend on how busy the machine is.
SHORT_LINE = """\
name: short-line
tf_s: 12
n_steps: 750
tau_s: 0.016
path: {type: line, start_m: [0.0, 0.0], velocity_mps: [0.05, 0.05]}
start: {x_m: 0.0, y_m: 0.0, theta_rad: 0.0, steering_rad: [0.7854, 0.7854]}
Q_diag: [1.0e+3, 1.0, 1.0e+2, 1.0, 1.0e+3]
R_diag: [1.0e-4, 1.0e-2, 1.0e-2]
"""


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    out = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert out.returncode == 0, f"{cmd}: exit {out.returncode}\n{out.stdout[-2000:]}\n{out.stderr[-4000:]}"
    return out


@pytest.fixture(scope="session")
def installed(tmp_path_factory, worker_id):
    """``(venv bin folder, site-packages folder, environment for the commands)``. Built once per
    test session: the workers of ``-n`` share their session's folder, and the first to take its
    lock builds the wheel and the venv there while the others wait for it."""
    base = tmp_path_factory.getbasetemp()
    shared = base if worker_id == "master" else base.parent     # pytest-N/, not pytest-N/popen-gwK/
    with open(shared / "wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        tmp = shared / "wheel"
        if not (tmp / "installed").is_file():
            shutil.rmtree(tmp, ignore_errors=True)        # a build that failed half-way
            tmp.mkdir()
            _build_and_install(tmp)
            (tmp / "installed").touch()
    site = Path(_run([tmp / "venv" / "bin" / "python", "-c",
                      "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    env = {k: v for k, v in os.environ.items() if k not in ("SWERVE_CONFIG", "PYTHONPATH")}
    env["XDG_CONFIG_HOME"] = str(tmp / "no-user-config")   # the shipped robot file applies
    return tmp / "venv" / "bin", site, env


def _build_and_install(tmp: Path) -> None:
    """Build the wheel from a clean copy of the tree and install it into ``tmp/venv``."""
    # Build from a clean copy: setuptools reuses an existing build/ folder, which may still hold
    # modules the tree no longer has.
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "out", "*.egg-info", "__pycache__", ".pytest_cache",
        ".hypothesis"))
    _run([sys.executable, "-m", "pip", "wheel", src, "--no-deps", "--quiet", "-w", tmp / "dist"],
         timeout=600)
    wheels = sorted((tmp / "dist").glob("swerve-*.whl"))
    assert len(wheels) == 1, wheels
    _run([sys.executable, "-m", "venv", tmp / "venv"], timeout=300)
    py = tmp / "venv" / "bin" / "python"
    # --no-compile: Python compiles what it imports; compiling all of SciPy and matplotlib ahead is
    # most of an install's CPU time and checks nothing of the wheel
    _run([py, "-m", "pip", "install", "--quiet", "--no-compile", wheels[0]], timeout=900)


@pytest.fixture()
def empty_dir(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    return d


def test_wheel_installs_one_package_with_its_configs(installed):
    _, site, _ = installed
    stray = [name for name in STRAY if (site / name).exists()]
    assert stray == [], f"top-level packages besides swerve in {site}: {stray}"
    for name in ("robot.yaml", "emulator.yaml", "models/xh430-w210.yaml", "trajectories/line.yaml"):
        assert (site / "swerve" / "configs" / name).is_file(), name
    assert not (site / "swerve" / "controller" / "online.py").exists()
    # every module of the checkout's parts is in the wheel (a package missing from
    # pyproject.toml's list would leave its command broken only after installation)
    missing = [str(py.relative_to(ROOT)) for part in (*STRAY, "testing")
               for py in (ROOT / part).rglob("*.py")
               if "__pycache__" not in py.parts
               and not (site / "swerve" / py.relative_to(ROOT)).is_file()]
    assert missing == [], f"modules of the checkout not installed by the wheel: {missing}"


def test_sim_runs_from_an_empty_folder_on_the_shipped_config(installed, empty_dir):
    bin_dir, site, env = installed
    out = _run([bin_dir / "swerve", "sim", "--trajectory", "line", "--json"], cwd=empty_dir, env=env,
               timeout=300)
    res = json.loads(out.stdout)
    assert res["trajectory"] == "line" and res["final_position_error_m"] < 0.01
    assert res["config_source"] == "shipped"
    assert Path(res["config"]) == site / "swerve" / "configs" / "robot.yaml"


def test_emulate_and_scan_find_eight_servos(installed, empty_dir):
    bin_dir, _, env = installed
    emu = subprocess.Popen([bin_dir / "swerve", "emulate"], cwd=empty_dir, env=env, text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        first = emu.stdout.readline().split()
        assert first[:1] == ["PORT"], (first, emu.stderr.read() if emu.poll() is not None else "")
        out = _run([bin_dir / "swerve", "scan", "--port", first[1]], cwd=empty_dir, env=env, timeout=120)
        assert f"{first[1]} at 1000000 bps: 8 servo(s)" in out.stdout
        ids = [int(line.split()[0]) for line in out.stdout.splitlines()[2:]]
        assert ids == list(range(1, 9))
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(timeout=30)
    assert emu.returncode == 0, emu.stderr.read()


def test_short_emulated_run_from_an_empty_folder(installed, empty_dir):
    """``swerve config init`` then ``swerve run --emulate --lockstep`` on that file (``$SWERVE_CONFIG``).

    The copy's Bus Watchdog and failed-read limit are raised, as in the stack tests."""
    import yaml

    bin_dir, _, env = installed
    _run([bin_dir / "swerve", "config", "init", "cfg"], cwd=empty_dir, env=env, timeout=60)
    robot = empty_dir / "cfg" / "robot.yaml"
    doc = yaml.safe_load(robot.read_text())
    doc["safety"].update(bus_watchdog_s=0.5, max_consecutive_timeouts=10)
    robot.write_text(yaml.safe_dump(doc))
    (empty_dir / "short-line.yaml").write_text(SHORT_LINE)
    out = _run([bin_dir / "swerve", "run", "--emulate", "--trajectory", "short-line.yaml",
                "--lockstep", "--log", "runlog", "--json"], cwd=empty_dir,
               env={**env, "SWERVE_CONFIG": "cfg/robot.yaml"}, timeout=300)
    assert out.stderr.splitlines()[0] == "config: cfg/robot.yaml ($SWERVE_CONFIG)"
    s = json.loads(out.stdout)
    assert s["completed"] is True and s["trajectory"] == "short-line"
    assert s["config"] == "cfg/robot.yaml" and s["config_source"] == "$SWERVE_CONFIG"
    assert s["cycles"] + s["missed_slots"] >= 750 and s["final_position_error_m"] < 0.05
    assert (empty_dir / "runlog" / "metadata.yaml").is_file()


#: The README's example for the pytest plugin, as a user would paste it into their repository.
PLUGIN_EXAMPLE = (ROOT / "tests" / "testing" / "test_testing_plugin.py").read_text()


def test_the_pytest_plugin_works_from_the_installed_wheel(installed, empty_dir):
    """A user's own repository: pytest installed beside the wheel, the README's example pasted in."""
    bin_dir, _, env = installed
    _run([bin_dir / "python", "-m", "pip", "install", "--quiet", "--no-compile", "pytest"], env=env, timeout=600)
    (empty_dir / "test_drive.py").write_text(PLUGIN_EXAMPLE)
    out = _run([bin_dir / "python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_drive.py"],
               cwd=empty_dir, env=env, timeout=600)
    assert "3 passed" in out.stdout, out.stdout
