"""Bad input to every ``swerve`` command: one line of error, a non-zero exit, nothing half-written.

Each case runs the real ``swerve`` command (the console script's function) in a child process
forked from one interpreter that has imported swerve once (:mod:`tests.command_server`; a few
cases also run in a fresh interpreter and must end the same, byte for byte), and asserts:

- a non-zero exit status that is not the "bug" status (70);
- exactly one line on stderr, with no ``Traceback`` and no "internal error";
- no partial output: the case's output file does not exist afterwards, and no temporary file
  is left in the work folder;
- it ends: the subprocess timeout is a hang guard, generous on purpose (no timing verdict).

Input classes: NaN, infinities, negative, zero, huge, wrong type, missing file, directory instead
of a file, binary file, empty file, unwritable output (a read-only file system; a file where a
folder should be: the tests run as root, which ignores permission bits), emulator faults naming
absent servos, a link path that exists, trajectories too long to hold, an endless device
(``/dev/zero``), a named pipe, a YAML "billion laughs" alias bomb.
"""
from __future__ import annotations

import io
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from swerve.configs import shipped

from .command_server import CommandServer
from .tools.logs import synthetic


pytestmark = pytest.mark.slow      # about 140 commands, most refused within a few ms of their start

#: Hang guard for one command, s (a healthy case takes about one second).
HANG_GUARD_S = 180
#: Status ``swerve`` uses for a bug (an unexpected exception).
EXIT_BUG = 70

# (id, argv; "{W}" is the work folder with the files of the fixture below, output: the path the
# command must not leave behind, relative to the work folder, or None)
CASES: list[tuple[str, list[str], str | None]] = [
    # --- emulate -------------------------------------------------------------------------
    ("emulate-time-scale-nan", ["emulate", "--time-scale", "nan"], None),
    ("emulate-time-scale-inf", ["emulate", "--time-scale", "inf"], None),
    ("emulate-time-scale-negative", ["emulate", "--time-scale", "-1"], None),
    ("emulate-time-scale-huge", ["emulate", "--time-scale", "1e300"], None),
    ("emulate-time-scale-word", ["emulate", "--time-scale", "fast"], None),
    ("emulate-clock-hz-nan", ["emulate", "--clock-hz", "nan"], None),
    ("emulate-clock-hz-zero", ["emulate", "--clock-hz", "0"], None),
    ("emulate-clock-hz-negative", ["emulate", "--clock-hz", "-1000"], None),
    ("emulate-clock-hz-inf", ["emulate", "--clock-hz", "inf"], None),
    ("emulate-ids-huge", ["emulate", "--ids", "1-100000000"], None),
    ("emulate-ids-253", ["emulate", "--ids", "250-253"], None),
    ("emulate-ids-reversed", ["emulate", "--ids", "8-1"], None),
    ("emulate-ids-word", ["emulate", "--ids", "one"], None),
    ("emulate-ids-repeated", ["emulate", "--ids", "1,1"], None),
    ("emulate-baud-zero", ["emulate", "--baud", "0"], None),
    ("emulate-baud-negative", ["emulate", "--baud", "-57600"], None),
    ("emulate-baud-float", ["emulate", "--baud", "1e6"], None),
    ("emulate-faults-vanish-absent", ["emulate", "--frozen", "--ids", "1-8", "--faults", "vanish=99"], None),
    ("emulate-faults-hwerror-absent", ["emulate", "--frozen", "--ids", "1", "--faults", "hwerror=5:overload"], None),
    ("emulate-faults-drop-nan", ["emulate", "--frozen", "--faults", "drop=nan"], None),
    ("emulate-faults-drop-2", ["emulate", "--frozen", "--faults", "drop=2"], None),
    ("emulate-faults-garbage", ["emulate", "--frozen", "--faults", "drop"], None),
    ("emulate-noise-nan", ["emulate", "--noise", "position=nan"], None),
    ("emulate-link-exists", ["emulate", "--frozen", "--ids", "1", "--link", "{W}/empty.yaml"], None),
    ("emulate-link-in-missing-dir", ["emulate", "--frozen", "--ids", "1", "--link", "{W}/no/such/link"], None),
    ("emulate-config-missing", ["emulate", "--config", "{W}/missing.yaml"], None),
    ("emulate-config-dir", ["emulate", "--config", "{W}/dir"], None),
    ("emulate-config-binary", ["emulate", "--config", "{W}/binary.yaml"], None),
    ("emulate-config-empty", ["emulate", "--config", "{W}/empty.yaml"], None),
    ("emulate-emulator-config-binary", ["emulate", "--emulator-config", "{W}/binary.yaml"], None),
    ("emulate-status-file-frozen", ["emulate", "--frozen", "--status-file", "{W}/status.json"], "status.json"),
    ("emulate-status-file-unwritable", ["emulate", "--physics", "--status-file", "/proc/swerve-status.json"],
     None),
    # --- scan -----------------------------------------------------------------------------
    ("scan-port-missing", ["scan", "--port", "{W}/no-such-port", "--ids", "1"], None),
    ("scan-port-dir", ["scan", "--port", "{W}/dir", "--ids", "1"], None),
    ("scan-port-regular-file", ["scan", "--port", "{W}/empty.yaml", "--ids", "1"], None),
    ("scan-timeout-nan", ["scan", "--port", "{W}/no-such-port", "--timeout-margin-ms", "nan"], None),
    ("scan-timeout-inf", ["scan", "--port", "{W}/no-such-port", "--timeout-margin-ms", "inf"], None),
    ("scan-timeout-negative", ["scan", "--port", "{W}/no-such-port", "--timeout-margin-ms", "-1"], None),
    ("scan-baud-zero", ["scan", "--port", "{W}/no-such-port", "--baud", "0"], None),
    ("scan-ids-300", ["scan", "--port", "{W}/no-such-port", "--ids", "0-300"], None),
    # --- synth ----------------------------------------------------------------------------
    ("synth-trajectory-unknown", ["synth", "--trajectory", "spiral", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-missing", ["synth", "--trajectory", "{W}/missing.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-dir", ["synth", "--trajectory", "{W}/dir.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-binary", ["synth", "--trajectory", "{W}/binary.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-empty", ["synth", "--trajectory", "{W}/empty.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-csv-binary", ["synth", "--trajectory", "{W}/binary.csv", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-too-long", ["synth", "--trajectory", "{W}/huge.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-trajectory-nan", ["synth", "--trajectory", "{W}/nan.yaml", "--out", "{W}/g.npz"], "g.npz"),
    ("synth-out-suffix", ["synth", "--trajectory", "line", "--out", "{W}/g.txt"], "g.txt"),
    ("synth-out-read-only-fs", ["synth", "--trajectory", "line", "--out", "/proc/swerve-g.npz"], None),
    ("synth-out-under-a-file", ["synth", "--trajectory", "line", "--out", "{W}/empty.yaml/g.npz"], None),
    ("synth-out-is-a-dir", ["synth", "--trajectory", "line", "--out", "{W}/dir.npz"], None),
    ("synth-target-ratio-nan", ["synth", "--trajectory", "line", "--target-ratio", "nan"], None),
    ("synth-max-iter-zero", ["synth", "--trajectory", "line", "--max-iter", "0"], None),
    ("synth-max-iter-float", ["synth", "--trajectory", "line", "--max-iter", "2.5"], None),
    ("synth-config-binary", ["synth", "--trajectory", "line", "--config", "{W}/binary.yaml"], None),
    ("synth-config-empty", ["synth", "--trajectory", "line", "--config", "{W}/empty.yaml"], None),
    ("synth-config-dir", ["synth", "--trajectory", "line", "--config", "{W}/dir"], None),
    ("synth-config-endless-device", ["synth", "--trajectory", "line", "--config", "/dev/zero"], None),
    ("synth-config-fifo", ["synth", "--trajectory", "line", "--config", "{W}/fifo.yaml"], None),
    ("synth-config-alias-bomb", ["synth", "--trajectory", "line", "--config", "{W}/bomb.yaml"], None),
    ("synth-trajectory-alias-bomb", ["synth", "--trajectory", "{W}/bomb.yaml"], None),
    # --- sim ------------------------------------------------------------------------------
    ("sim-gains-missing", ["sim", "--trajectory", "line", "--gains", "{W}/missing.npz"], None),
    ("sim-gains-dir", ["sim", "--trajectory", "line", "--gains", "{W}/dir.npz"], None),
    ("sim-gains-empty-npz", ["sim", "--trajectory", "line", "--gains", "{W}/empty.npz"], None),
    ("sim-gains-empty-dat", ["sim", "--trajectory", "line", "--gains", "{W}/empty.dat"], None),
    ("sim-gains-truncated-npz", ["sim", "--trajectory", "line", "--gains", "{W}/truncated.npz"], None),
    ("sim-gains-truncated-dat", ["sim", "--trajectory", "line", "--gains", "{W}/truncated.dat"], None),
    ("sim-gains-binary-npz", ["sim", "--trajectory", "line", "--gains", "{W}/binary.npz"], None),
    ("sim-gains-binary-dat", ["sim", "--trajectory", "line", "--gains", "{W}/binary.dat"], None),
    ("sim-gains-wrong-suffix", ["sim", "--trajectory", "line", "--gains", "{W}/empty.yaml"], None),
    ("sim-gains-complex", ["sim", "--trajectory", "line", "--gains", "{W}/complex.npz"], None),
    ("sim-gains-huge-header", ["sim", "--trajectory", "line", "--gains", "{W}/huge-header.npz"], None),
    ("sim-gains-short-phi", ["sim", "--trajectory", "line", "--gains", "{W}/short-phi.npz"], None),
    ("sim-gains-meta-list-npz", ["sim", "--trajectory", "line", "--gains", "{W}/meta-list.npz"], None),
    ("sim-gains-meta-list-dat", ["sim", "--trajectory", "line", "--gains", "{W}/meta-list.dat"], None),
    ("sim-robot-wheel-radius-tiny", ["sim", "--trajectory", "line", "--config", "{W}/tiny-wheel.yaml"], None),
    ("sim-robot-timeouts-huge", ["sim", "--trajectory", "line", "--config", "{W}/many-timeouts.yaml"], None),
    ("emulate-control-on-a-file", ["emulate", "--lockstep", "--control", "{W}/empty.yaml"], None),
    ("sim-x0-nan", ["sim", "--trajectory", "line", "--x0", "nan,0,0,0,0"], None),
    ("sim-x0-short", ["sim", "--trajectory", "line", "--x0", "1,2"], None),
    ("sim-x0-words", ["sim", "--trajectory", "line", "--x0", "a,b,c,d,e"], None),
    ("sim-diverges", ["sim", "--trajectory", "line", "--x0", "5,5,3,0,0"], None),
    ("sim-tolerance-nan", ["sim", "--trajectory", "line", "--tolerance-m", "nan"], None),
    ("sim-plot-read-only-fs", ["sim", "--trajectory", "line", "--plot", "/proc/swerve-plots"], None),
    # --- run (each fails before a servo is touched) ---------------------------------------
    ("run-time-scale-zero", ["run", "--trajectory", "line", "--emulate", "--time-scale", "0"], None),
    ("run-time-scale-nan", ["run", "--trajectory", "line", "--emulate", "--time-scale", "nan"], None),
    ("run-time-scale-inf", ["run", "--trajectory", "line", "--emulate", "--time-scale", "inf"], None),
    ("run-timeout-margin-nan", ["run", "--trajectory", "line", "--emulate", "--timeout-margin-ms", "nan"], None),
    ("run-gains-empty", ["run", "--trajectory", "line", "--emulate", "--gains", "{W}/empty.npz",
                         "--log", "{W}/runlog"], "runlog"),
    ("run-gains-truncated", ["run", "--trajectory", "line", "--emulate", "--gains", "{W}/truncated.npz",
                             "--log", "{W}/runlog"], "runlog"),
    ("run-port-missing", ["run", "--trajectory", "line", "--port", "{W}/no-such-port", "--log", "{W}/runlog"],
     "runlog"),
    ("run-trajectory-binary", ["run", "--trajectory", "{W}/binary.yaml", "--emulate", "--log", "{W}/runlog"],
     "runlog"),
    ("run-faults-vanish-absent", ["run", "--trajectory", "line", "--emulate", "--faults", "vanish=99",
                                  "--log", "{W}/runlog"], None),
    # --- demo -----------------------------------------------------------------------------
    ("demo-time-scale-nan", ["demo", "--time-scale", "nan", "--out", "{W}/demo"], "demo"),
    ("demo-time-scale-zero", ["demo", "--time-scale", "0", "--out", "{W}/demo"], "demo"),
    ("demo-trajectory-unknown", ["demo", "--trajectories", "spiral", "--out", "{W}/demo"], "demo"),
    ("demo-trajectories-empty", ["demo", "--trajectories", "", "--out", "{W}/demo"], "demo"),
    ("demo-trajectories-commas", ["demo", "--trajectories", ",,", "--out", "{W}/demo"], "demo"),
    ("demo-workers-zero", ["demo", "--workers", "0", "--out", "{W}/demo"], "demo"),
    ("demo-workers-word", ["demo", "--workers", "all", "--out", "{W}/demo"], "demo"),
    # --- tune (each fails before a servo is touched) --------------------------------------
    ("tune-pwm-zero", ["tune", "--emulate", "--pwm", "0"], None),
    ("tune-pwm-above-one", ["tune", "--emulate", "--pwm", "1.5"], None),
    ("tune-pwm-nan", ["tune", "--emulate", "--pwm", "nan"], None),
    ("tune-id-300", ["tune", "--emulate", "--id", "300"], None),
    ("tune-id-negative", ["tune", "--emulate", "--id", "-1"], None),
    ("tune-current-max-negative", ["tune", "--emulate", "--current-max", "-1"], None),
    ("tune-settle-max-nan", ["tune", "--emulate", "--settle-max", "nan"], None),
    ("tune-overshoot-max-huge", ["tune", "--emulate", "--overshoot-max", "2"], None),
    ("tune-velocity-step-zero", ["tune", "--emulate", "--velocity-step", "0"], None),
    ("tune-seed-negative", ["tune", "--emulate", "--seed", "-3"], None),
    ("tune-port-missing", ["tune", "--port", "{W}/no-such-port"], None),
    ("tune-prior-binary", ["tune", "--emulate", "--prior", "{W}/binary.yaml"], None),
    # --- plot / export-csv ----------------------------------------------------------------
    ("export-log-missing", ["export-csv", "{W}/missing-log", "--out", "{W}/x.csv"], "x.csv"),
    ("export-log-empty-dir", ["export-csv", "{W}/dir", "--out", "{W}/x.csv"], "x.csv"),
    ("export-log-binary", ["export-csv", "{W}/binary.mcap", "--out", "{W}/x.csv"], "x.csv"),
    ("export-log-empty", ["export-csv", "{W}/empty.mcap", "--out", "{W}/x.csv"], "x.csv"),
    ("export-log-not-swerve", ["export-csv", "{W}/other.mcap", "--out", "{W}/x.csv"], "x.csv"),
    ("export-out-read-only-fs", ["export-csv", "{W}/log", "--out", "/proc/swerve.csv"], None),
    ("export-out-under-a-file", ["export-csv", "{W}/log", "--out", "{W}/empty.yaml/x.csv"], None),
    ("export-out-is-a-dir", ["export-csv", "{W}/log", "--out", "{W}/dir"], None),
    ("plot-log-missing", ["plot", "{W}/missing-log", "--out", "{W}/plots"], "plots"),
    ("plot-log-binary", ["plot", "{W}/binary.mcap", "--out", "{W}/plots"], "plots"),
    ("plot-out-read-only-fs", ["plot", "{W}/log", "--out", "/proc/swerve-plots"], None),
    ("plot-out-under-a-file", ["plot", "{W}/log", "--out", "{W}/empty.yaml/plots"], None),
    ("plot-sim-binary", ["plot", "{W}/log", "--out", "{W}/plots", "--sim", "{W}/binary.mcap"], None),
    # --- calibrate / doctor ----------------------------------------------------------------
    ("calibrate-distance-nan", ["calibrate", "--emulate", "--distance", "nan"], None),
    ("calibrate-speed-zero", ["calibrate", "--emulate", "--speed", "0"], None),
    ("calibrate-time-scale-inf", ["calibrate", "--emulate", "--time-scale", "inf"], None),
    ("doctor-cycles-zero", ["doctor", "--emulate", "--cycles", "0"], None),
    ("doctor-timeout-nan", ["doctor", "--emulate", "--timeout-margin-ms", "nan"], None),
    ("doctor-port-missing", ["doctor", "--port", "{W}/no-such-port"], None),
    # --- config ---------------------------------------------------------------------------
    ("config-init-read-only-fs", ["config", "init", "/proc/swerve-config"], None),
    ("config-init-under-a-file", ["config", "init", "{W}/empty.yaml/cfg"], None),
    # --- the command line itself ------------------------------------------------------------
    ("no-command", [], None),
    ("unknown-command", ["fly"], None),
    ("unknown-option", ["sim", "--trajectory", "line", "--warp", "9"], None),
]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A folder of bad files: empty, binary, a directory, truncated gains, a foreign MCAP, a good log."""
    w = tmp_path_factory.mktemp("bad")
    rnd = os.urandom(4096)
    for name in ("empty.yaml", "empty.npz", "empty.dat", "empty.mcap"):
        (w / name).write_bytes(b"")
    for name in ("binary.yaml", "binary.npz", "binary.dat", "binary.csv", "binary.mcap"):
        (w / name).write_bytes(rnd)
    for name in ("dir", "dir.yaml", "dir.npz"):
        (w / name).mkdir()
    (w / "huge.yaml").write_text("name: huge\ntf_s: 90000\ntau_s: 0.016\n"
                                 "path: {type: line, start_m: [0.0, 0.0], velocity_mps: [0.05, 0.05]}\n")
    (w / "nan.yaml").write_text("name: nan\ntf_s: .nan\ntau_s: 0.016\n"
                                "path: {type: line, start_m: [0.0, 0.0], velocity_mps: [0.05, 0.05]}\n")
    subprocess.run([sys.executable, "-m", "swerve.tools.cli", "synth", "--trajectory", "line", "--out",
                    str(w / "good.npz"), "--quiet"], check=True, capture_output=True, timeout=HANG_GUARD_S)
    os.mkfifo(w / "fifo.yaml")                       # opening it would block until a writer comes
    (w / "bomb.yaml").write_text("a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")))
    (w / "truncated.npz").write_bytes((w / "good.npz").read_bytes()[:3000])
    _hostile_gains(w)
    robot = Path(shipped("robot.yaml")).read_text()
    (w / "tiny-wheel.yaml").write_text(robot.replace("wheel_radius_m: 0.033", "wheel_radius_m: 1.0e-300"))
    (w / "many-timeouts.yaml").write_text(robot.replace("max_consecutive_timeouts: 3",
                                                        "max_consecutive_timeouts: 1000000000000000000000000000000"))
    (w / "truncated.dat").write_bytes((w / "good.dat").read_bytes()[:5000])
    synthetic.write(w / "log", synthetic.records(50))
    from mcap.writer import Writer

    with (w / "other.mcap").open("wb") as fh:        # a valid MCAP that is not a swerve log
        mw = Writer(fh)
        mw.start()
        mw.finish()
    return w


def _hostile_gains(w: Path) -> None:
    """Gain files that are wrong in one way each, made from ``good.npz``."""
    import json

    import numpy as np

    with np.load(w / "good.npz") as z:
        good = {k: z[k] for k in z.files}
    variants = {"complex": {"K": good["K"] * (1 + 1j)}, "short-phi": {"phi_rad": good["phi_rad"][:2]},
                "meta-list": {"meta": np.array(json.dumps([1, 2]))}}
    for name, change in variants.items():
        np.savez(w / f"{name}.npz", **{**good, **change})
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (200_000_000, 3, 5)})
    with zipfile.ZipFile(w / "huge-header.npz", "w") as zf:
        for k, v in good.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, v)
            zf.writestr(f"{k}.npy", header.getvalue() + b"\0" * 64 if k == "K" else buf.getvalue())
    dat = (w / "good.dat").read_text().splitlines(keepends=True)
    (w / "meta-list.dat").write_text("".join("# meta: [1, 2]\n" if ln.startswith("# meta:") else ln
                                             for ln in dat))


def _leftovers(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*.tmp"))


def _environment(work: Path) -> dict[str, str]:
    env = dict(os.environ, XDG_STATE_HOME=str(work / "state"), XDG_CONFIG_HOME=str(work / "xdg"))
    env.pop("SWERVE_CONFIG", None)
    return env


@pytest.fixture(scope="module")
def server(work, tmp_path_factory):
    """The command server of this module's cases: in the work folder, with their environment."""
    with CommandServer(work, _environment(work), tmp_path_factory.mktemp("streams")) as srv:
        yield srv


def _args(argv: list[str], work: Path) -> list[str]:
    return [a.replace("{W}", str(work)) for a in argv]


def test_importing_every_command_prints_nothing(server):
    """What a forked command does not repeat, checked once: a fresh command's imports are silent."""
    assert server.import_output == ""


#: Cases that also run in a fresh interpreter: a bad option, a bad value the work refuses, a file
#: it cannot write (OSError), the command line itself.
FRESH = ("emulate-time-scale-nan", "emulate-faults-vanish-absent", "synth-out-read-only-fs", "no-command")


@pytest.mark.parametrize("argv", [pytest.param(a, id=i) for i, a, _ in CASES if i in FRESH])
def test_a_forked_command_ends_as_a_fresh_one(argv, work, server):
    args = _args(argv, work)
    fresh = subprocess.run([sys.executable, "-m", "swerve.tools.cli", *args], capture_output=True, text=True,
                           timeout=HANG_GUARD_S, cwd=work, env=_environment(work), stdin=subprocess.DEVNULL)
    forked = server.run(args, HANG_GUARD_S)
    assert (forked.returncode, forked.stdout, forked.stderr) == (fresh.returncode, fresh.stdout, fresh.stderr)


@pytest.mark.parametrize("argv,output", [pytest.param(a, o, id=i) for i, a, o in CASES])
def test_bad_input_is_one_line_and_a_non_zero_exit(argv, output, work, server):
    before = _leftovers(work)
    out = server.run(_args(argv, work), HANG_GUARD_S)
    lines = out.stderr.strip().splitlines()
    assert out.returncode not in (0, EXIT_BUG), out.stderr
    assert len(lines) == 1, out.stderr
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr
    if output is not None:
        assert not (work / output).exists(), f"{output} was left behind"
    assert _leftovers(work) == before
