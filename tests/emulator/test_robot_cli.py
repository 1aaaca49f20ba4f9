"""``swerve emulate --physics`` as a subprocess: the status file gives the true pose to another
process, beside the bus. Deterministic: ``--time-scale 0`` (no clock), so nothing
moves and nothing depends on machine load; the moving robot is covered in test_robot_drive.py."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

from swerve.driver.bus import Bus
from swerve.driver.robot_config import load_robot_config
from swerve.driver.wheelset import WheelSet

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "swerve.tools.cli", "emulate"]


def test_emulate_physics_publishes_the_true_pose_beside_the_bus(tmp_path):
    status = tmp_path / "pose.json"
    cfg = load_robot_config(ROOT / "configs" / "robot.yaml")
    proc = subprocess.Popen([*CLI, "--physics", "--time-scale", "0", "--status-file", str(status), "-v"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().split()
        assert port[0] == "PORT"
        doc = json.loads(status.read_text())            # written before PORT is printed
        with Bus(port[1], cfg.link.baud, timeout_margin_s=1.0) as bus, WheelSet(bus, cfg) as wheels:
            wheels.configure()                          # the physics servos answer like the bare bus
            wheels.enable()
            wheels.write_goals([1.0] * 4, [0.2] * 4)
            state = wheels.read_state()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    final = json.loads(status.read_text())              # rewritten at exit
    assert doc["t_s"] == 0.0 and doc["pose"] == [0.0, 0.0, 0.0]
    assert final["t_s"] == 0.0 and final["pose"] == [0.0, 0.0, 0.0]   # frozen clock: nothing moved
    assert [w["name"] for w in final["wheels"]] == [w.name for w in cfg.wheels]
    assert state.steer_rad == (0.0, 0.0, 0.0, 0.0)
    assert "8 x xh430-w210" in err.lower()


def test_status_file_needs_the_robot_body():
    proc = subprocess.run([*CLI, "--ids", "1", "--status-file", "x.json"], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert "status file needs the robot body" in proc.stderr
