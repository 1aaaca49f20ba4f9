"""A writer killed with SIGKILL leaves a log readable to its last flushed cycle."""
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from swerve.tools.cli import main
from swerve.tools.logs import read_log, repair_log

SCRIPT = Path(__file__).with_name("synthetic.py")
#: Hang guard for the writer to exit once signalled, s: generous on purpose (a loaded host can take
#: seconds to close the log and exit); a writer that ignored the signal exits after its 60 s sleep
#: with status 0, which the return-code check names.
EXIT_GUARD_S = 120


def _kill_after(bag: Path, n: int, flush_every: int, sig=signal.SIGKILL) -> None:
    proc = subprocess.Popen([sys.executable, str(SCRIPT), str(bag), str(n), str(flush_every)],
                            stdout=subprocess.PIPE, text=True)
    try:
        for line in proc.stdout:
            if line.strip() == f"wrote {n}":
                break
        os.kill(proc.pid, sig)
    finally:
        proc.wait(timeout=EXIT_GUARD_S)
        proc.stdout.close()
    assert proc.returncode == -sig  # Python re-raises an unhandled SIGINT after cleanup


@pytest.mark.parametrize("flush_every", [1, 8], ids=["flush1", "flush8"])
def test_sigkill_mid_run_recovers_flushed_cycles(tmp_path, flush_every):
    n = 237
    bag = tmp_path / "killed"
    _kill_after(bag, n, flush_every)
    assert not (bag / "metadata.yaml").exists()
    log = read_log(bag)
    assert not log.clean
    # the writer is asleep after cycle n when killed: everything up to the last flush is there
    assert len(log) == n - n % flush_every >= n - (flush_every - 1)
    assert (log.cycle == range(len(log))).all()
    assert log.recovery_note == f"log was not closed cleanly; recovered {len(log)} cycles"


def test_truncated_tail_and_repair(tmp_path, capsys):
    bag = tmp_path / "killed"
    _kill_after(bag, 100, 1)
    mcap = next(bag.glob("*.mcap"))
    with mcap.open("r+b") as f:  # a half-written last chunk
        f.truncate(mcap.stat().st_size - 1000)
    log = read_log(bag)
    assert len(log) == 99  # the cut chunk (cycle 100) is dropped, nothing else
    assert main(["export-csv", str(bag), "--out", str(tmp_path / "k.csv")]) == 0
    assert f"recovered {len(log)} cycles" in capsys.readouterr().err
    fixed = repair_log(bag)
    assert (fixed / "metadata.yaml").exists() and read_log(fixed).clean
    with AnyReader([fixed]) as reader:
        n = sum(1 for c, _, _ in reader.messages() if c.topic == "/swerve/cycle")
    assert n == len(log)


def test_ctrl_c_closes_the_log_cleanly(tmp_path):
    bag = tmp_path / "interrupted"
    _kill_after(bag, 50, 8, sig=signal.SIGINT)  # KeyboardInterrupt leaves the with block
    assert (bag / "metadata.yaml").exists()
    log = read_log(bag)
    assert log.clean and len(log) == 50
    with AnyReader([bag]) as reader:
        assert reader.message_count == 1 + 6 * 50  # metadata + 6 topics per cycle (no /sim_pose)
