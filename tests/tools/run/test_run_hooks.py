"""``swerve run`` on the emulator with ``--on-servo-fault recover`` and ``--live``, in lockstep: a
servo's overload is injected at a fixed robot time, the run recovers and completes, and a
WebSocket client connected during the run sees the run log's channels and receives their
messages. Robot time is the emulator's, so the tracking numbers are the same on any machine."""
from __future__ import annotations

import asyncio
import socket
import threading
import time

import pytest

from swerve.tools import live

from ..test_live import _client

pytestmark = pytest.mark.slow
#: Robot time at which the overload is injected, s (the line runs 40 s after about 1 s of set-up).
FAULT_AT_S = 12.0
#: Wall seconds the run waits, cycle by cycle, for the live client before it goes on regardless
#: (robot time stands still meanwhile, so waiting changes no number of the run).
CLIENT_WAIT_S = 60.0
#: Largest true-pose error of this run, m. Lockstep makes it the same on every run (14.46 mm
#: measured, replies through the robot file's 1 ms USB adapter): the bound only leaves room for
#: round-off across platforms.
MAX_ERROR_M = 0.015


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_overload_mid_run_is_recovered_while_a_live_client_watches():
    from swerve.configs import shipped
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    port = _free_port()
    want = {"/joint_states", "/trajectory", "/odom", "/reference", "/true_pose", live.LIVE_TOPIC}
    seen: dict = {}
    client_done = threading.Event()

    def watch():
        try:
            for _ in range(600):              # the server starts once the robot is configured
                try:
                    seen["channels"], seen["got"] = asyncio.run(
                        _client(f"ws://127.0.0.1:{port}", lambda: None, want, timeout_s=30))
                    return
                except OSError:
                    time.sleep(0.1)
        finally:
            client_done.set()

    injected: list[float] = []
    give_up = time.monotonic() + CLIENT_WAIT_S

    def on_cycle(fields, clock):
        if not injected and clock.now() >= FAULT_AT_S:
            clock.fault("hwerror", 3, "overload")      # served in bus order: after the read the loop has sent
            injected.append(clock.now())
        if not client_done.is_set() and time.monotonic() < give_up:
            client_done.wait(0.01)          # let the viewer connect: robot time does not pass

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    req = RunRequest(trajectory="line", config=shipped("robot.yaml"), emulate=True, lockstep=True,
                     time_scale=None, on_servo_fault="recover", live=f"127.0.0.1:{port}")
    s = run_tracking(req, on_cycle=on_cycle).summary
    watcher.join(timeout=40)
    assert injected and injected[0] == pytest.approx(FAULT_AT_S, abs=0.02), injected

    topics = {c["topic"] for c in seen.get("channels", {}).values()}
    assert want <= topics and want <= seen["got"].keys()

    assert s.clock == "lockstep"
    assert s.completed, s.abort_message
    assert s.servo_faults.on_servo_fault == "recover" and s.servo_faults.recoveries == 1
    steps = [line.split(": ", 1)[0].split()[-1] for line in s.servo_faults.recovery_steps]
    assert steps == ["fault", "stop", "reboot", "restore", "torque", "rehome", "resume"]
    assert "ID 3" in s.servo_faults.recovery_steps[2] and "0x20" in s.servo_faults.recovery_steps[2]
    # the recovery's waits ran on robot time: the other drive wheels came to a stop
    assert "stood still after" in s.servo_faults.recovery_steps[1], s.servo_faults.recovery_steps[1]
    assert s.live.live_published > 0
    # the odometry restarted from its estimate (the rebooted drive's wheel angle starts over)
    assert s.tracking.max_position_error_m < MAX_ERROR_M
    print(f"line with an overload on ID 3 at {injected[0]:.3f} s of robot time: "
          f"rms {s.tracking.rms_position_error_m * 1e3:.2f} mm, max {s.tracking.max_position_error_m * 1e3:.2f} mm, "
          f"final {s.tracking.final_position_error_m * 1e3:.2f} mm; recovery: {s.servo_faults.recovery_steps}; "
          f"live published {s.live.live_published}, dropped {s.live.live_dropped}; wall {s.wall_time_s:.1f} s")
