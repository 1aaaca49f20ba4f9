"""The process pool: the same results.csv with 1 and 2 workers, a refused scenario is a row,
a lost worker costs one retry, a stop signal keeps what finished and a rerun resumes it,
replay gives the row again."""
from __future__ import annotations

import csv
import io
import json
import os
import signal
import subprocess
import time
from functools import partial

import pytest

from swerve.core.errors import ConfigError
from swerve.tools.campaign.pool import Done, PoolEngine
from swerve.tools.campaign.runner import MAX_LOSSES, run_missing
from swerve.tools.campaign.scenario import Outcome, base_row, run_scenario, scenario, text
from swerve.tools.campaign.spec import load_campaign
from swerve.tools.campaign.store import Store

from .conftest import campaign_cmd, run_campaign


def rows(data: bytes) -> list[dict]:
    return list(csv.DictReader(io.StringIO(data.decode())))


@pytest.mark.slow
def test_one_and_two_workers_give_the_same_table_and_a_refused_run_is_a_row(tiny_file, tiny_pool, tmp_path):
    out = tmp_path / "out"
    proc = run_campaign("run", str(tiny_file), "--out", str(out), "--workers", "2", "--no-plots")
    assert (out / "results.csv").read_bytes() == tiny_pool
    ok, refused = rows(tiny_pool)
    assert (ok["index"], ok["status"], ok["faults"]) == ("0", "completed", "")
    assert float(ok["rms_position_error_m"]) > 0 and ok["cycles"] == "375"
    assert refused["status"] == "failed" and "overload" in refused["reason"] and refused["cycles"] == ""
    # both rows share the robot: same drawn values
    assert ok["tolerances.wheel_radius_scale[2]"] == refused["tolerances.wheel_radius_scale[2]"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["overall"]["count"] == dict(completed=1, stopped=0, failed=1)
    assert "swerve campaign replay" in proc.stdout


def test_a_different_file_for_a_results_folder_is_refused(tiny_file, tmp_path):
    out = tmp_path / "out"
    Store.open(out, load_campaign(tiny_file)).close()
    proc = run_campaign("run", "smoke", "--out", str(out), check=False)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "another campaign file" in proc.stderr


@pytest.mark.slow
def test_stop_signal_keeps_results_and_a_rerun_resumes(tiny_file, tiny_pool, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen(campaign_cmd("run", str(tiny_file), "--out", str(out), "--workers", "1", "--no-plots"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    records = out / "records.jsonl"
    deadline = time.monotonic() + 300
    while not (records.is_file() and records.read_text().count("\n") >= 1):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    kept = rows((out / "results.csv").read_bytes())
    assert 1 <= len(kept) <= 2 and kept == rows(tiny_pool)[:len(kept)]
    rerun = run_campaign("run", str(tiny_file), "--out", str(out), "--workers", "2", "--no-plots")
    assert f"{len(kept)} already in" in rerun.stdout
    assert (out / "results.csv").read_bytes() == tiny_pool


@pytest.mark.slow
def test_replay_gives_the_same_row(tiny_file, tiny_pool, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    Store.open(out, load_campaign(tiny_file)).close()
    (out / "results.csv").write_bytes(tiny_pool)
    proc = run_campaign("replay", str(out), "0", "--log", str(tmp_path / "log"))
    assert "same row as in results.csv" in proc.stderr
    assert (tmp_path / "log").is_dir()


class LosingEngine:
    """An engine whose workers die ``losses[index]`` times before running the scenario."""

    name, slots = "fake", 2

    def __init__(self, campaign, losses):
        self.campaign, self.losses, self.queue, self.closed = campaign, dict(losses), [], False

    def submit(self, index):
        self.queue.append(index)

    def wait(self):
        index = self.queue.pop(0)
        if self.losses.get(index, 0) > 0:
            self.losses[index] -= 1
            return Done(index, lost="killed")
        row = base_row(self.campaign, scenario(self.campaign, index))
        row.update(status="completed", reason="")
        return Done(index, Outcome(index, {k: text(v) for k, v in row.items()}, 0.1))

    def close(self):
        self.closed = True


def test_a_lost_worker_costs_one_retry_and_two_losses_fail_the_row(tmp_path):
    c = load_campaign("smoke")
    store = Store.open(tmp_path / "out", c)
    engine = LosingEngine(c, {1: 1, 2: MAX_LOSSES})
    stats = run_missing(store, engine, progress=False)
    assert engine.closed and stats.ran == c.scenarios and stats.failures == 1
    got = {int(r["index"]): r for r in Store(tmp_path / "out", c).rows()}
    assert got[1]["status"] == "completed"
    assert got[2]["status"] == "failed" and got[2]["reason"] == "worker lost 2 times: killed"
    assert len(got) == c.scenarios


def test_pool_reports_a_killed_worker_as_lost():
    engine = PoolEngine(partial(run_scenario, load_campaign("smoke")), 1)
    try:
        engine.submit(0)
        os.kill(engine._slots[0].proc.pid, signal.SIGKILL)
        done = engine.wait()
        assert done.index == 0 and done.outcome is None and "exited" in done.lost
    finally:
        engine.close()


def test_workers_must_be_positive():
    with pytest.raises(ConfigError):
        PoolEngine(partial(run_scenario, load_campaign("smoke")), 0)


def test_smoke_writes_summary_plots_and_replay_commands(smoke_pool):
    summary = json.loads((smoke_pool / "summary.json").read_text())
    assert summary["finished"] == summary["scenarios"] == 4
    assert sum(summary["overall"]["count"].values()) == 4
    assert {(g["trajectory"], g["calibrate"]) for g in summary["groups"]} == {
        (t, c) for t in ("trajectories/line-6s.yaml", "trajectories/circle-8s.yaml") for c in ("false", "true")}
    table = rows((smoke_pool / "results.csv").read_bytes())
    assert [r["calibrate"] for r in table] == ["false", "true"] * 2
    assert all(r["calibrated_wheel_radius_m"] != "" for r in table if r["calibrate"] == "true")
    assert all(r["calibrated_wheel_radius_m"] == "" for r in table if r["calibrate"] == "false")
    for name in ("cdf.png", "rms_position_error_m_vs_parameters.png"):
        assert (smoke_pool / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"swerve campaign replay {smoke_pool} " in (smoke_pool / "summary.md").read_text()
