"""Lockstep runs are repeatable: the same trajectory, config and seeds give a byte-identical CSV
export of the run log and the same summary (apart from host-measured fields), also when the
machine is loaded by another process during one of the runs, and whichever BLAS kernels and SIMD
paths NumPy picks for the CPU (a machine of another CPU generation gets other ones).

The runs track the shipped line for its first 10 s (:func:`short_line`, 625 cycles) instead of
its 40 s: the export writes every float in full (commands from the gains, the emulator's true
pose), so a bit that differs in the gain synthesis, the body fit or the motors' discretisation
shows from the first cycles on, and every cycle runs the same code as the later ones."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from swerve.configs import shipped
from swerve.tools.logs.bag import read_log
from swerve.tools.logs.csv_export import export_csv
from swerve.tools.run.orchestrate import RunRequest, run_tracking

pytestmark = pytest.mark.slow

#: Summary fields measured on the host (wall time, CPU time): they differ from run to run.
HOST_FIELDS = {"wall_time_s", "real_time_factor", "host_cpu_p50_ms", "host_cpu_p99_ms", "host_cpu_overruns",
               "emulator_physics_real_time_factor", "emulator_cpu_s", "loop_cpu_s", "loop_started_unix_s", "log"}
#: Dropped and corrupted replies and sensor noise, all drawn from seeded generators.
FAULTS = "drop=0.003,corrupt=0.003,seed=11"
NOISE = "position=0.5,current=0.002,seed=4"
#: Slack on the bus's reply deadlines, wall s: small, so on a loaded host many replies miss it and
#: are waited for through the emulator's reply gate (the outcome must not change).
MARGIN_S = 0.001
#: Robot time of the runs, s, and its cycles at the line's 16 ms step.
SHORT_TF_S, SHORT_CYCLES = 10, 625


@pytest.fixture(scope="module")
def short_line(tmp_path_factory) -> Path:
    """The shipped line trajectory cut to its first :data:`SHORT_TF_S` seconds."""
    text = Path(shipped("trajectories/line.yaml")).read_text()
    assert "tf_s: 40\nn_steps: 2500\n" in text
    path = tmp_path_factory.mktemp("trajectory") / "line.yaml"
    path.write_text(text.replace("tf_s: 40\nn_steps: 2500\n", f"tf_s: {SHORT_TF_S}\nn_steps: {SHORT_CYCLES}\n"))
    return path


def _run(log_dir, trajectory: Path):
    res = run_tracking(RunRequest(trajectory=str(trajectory), emulate=True, lockstep=True, time_scale=None,
                                  faults=FAULTS, noise=NOISE, log=log_dir, timeout_margin_s=MARGIN_S))
    return {k: v for k, v in res.summary.to_dict().items() if k not in HOST_FIELDS}


def test_two_lockstep_runs_export_byte_identical_csv(tmp_path, short_line):
    first = _run(tmp_path / "a", short_line)
    burner = subprocess.Popen([sys.executable, "-c", "while True: pass"])   # load the machine
    try:
        second = _run(tmp_path / "b", short_line)
    finally:
        burner.kill()
        burner.wait()
    assert first["completed"] and first["failed_reads"] > 0      # the faults did happen
    assert first["cycles"] == SHORT_CYCLES
    assert first == second
    a = export_csv(read_log(tmp_path / "a"), tmp_path / "a.csv").read_bytes()
    b = export_csv(read_log(tmp_path / "b"), tmp_path / "b.csv").read_bytes()
    assert len(a.splitlines()) == first["cycles"] + 1
    assert a == b


#: Machines as NumPy sees them: OpenBLAS kernels without and with FMA (``OPENBLAS_CORETYPE``), and
#: NumPy's own SIMD loops limited to the x86-64-v2 baseline (``NPY_DISABLE_CPU_FEATURES``); and as
#: numba sees them: the physics kernels compiled for a generic x86-64 CPU (``NUMBA_CPU_NAME``).
MACHINES = {
    "nehalem": {"OPENBLAS_CORETYPE": "Nehalem"},
    "haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "no-simd-dispatch": {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL X86_V3"},
    "generic-kernels": {"NUMBA_CPU_NAME": "generic"},
}


@pytest.mark.parametrize("profile", ["ideal", "realistic"])
def test_lockstep_csv_is_the_same_on_other_cpus(tmp_path, profile, other_cpu, short_line):
    """The gains are synthesised, the body fitted and the motors discretised in each run (each
    "machine" with an empty cache folder, so no Riccati solution or ZOH matrix comes from another's
    run), so any BLAS- or SIMD-dependent step on the way would change the export."""
    csv = {}
    for name, env in MACHINES.items():
        log = tmp_path / name
        other_cpu({**env, "XDG_CACHE_HOME": str(tmp_path / f"cache-{name}")}, "-m", "swerve.tools.cli", "run", "--trajectory", str(short_line), "--emulate", "--lockstep",
                  "--emulator-config", profile, "--log", str(log))
        csv[name] = export_csv(read_log(log), tmp_path / f"{name}.csv").read_bytes()
    assert len(csv["nehalem"].splitlines()) == SHORT_CYCLES + 1
    assert csv["haswell"] == csv["nehalem"]
    assert csv["no-simd-dispatch"] == csv["nehalem"]
    assert csv["generic-kernels"] == csv["nehalem"]
