"""The typed run summary: flat keys as ``swerve run --json`` prints them, absent fields left out."""
import json
import math

from swerve.tools.run.summary import EmulatorStats, LoopTiming, RunSummary, tracking_errors

METRICS = dict(rms_position_error_m=0.003, max_position_error_m=0.005, final_position_error_m=0.004,
               max_abs_v1_mps=0.13, max_abs_steer_rate_radps=4.0, cost=12.5, max_reference_lag_s=0.2,
               saturated_fraction=0.1, duration_s=40.0)
TIMING = LoopTiming(3.2, 3.2, 3.3, 5.0, 2500, 1, 2)


def test_summary_flattens_its_records_with_unit_suffixed_keys():
    import numpy as np

    s = RunSummary("line", "emulator", "/x/robot.yaml", "shipped", 5.0, True, 2500, 3, TIMING,
                   tracking=tracking_errors(METRICS, "true_pose", True, np.array([0.001, 0.002])),
                   bus_stray_replies=4, log="out/runs/line", emulator=EmulatorStats(0, 4.9, 0.1))
    d = s.to_dict()
    assert d["config"] == "/x/robot.yaml" and d["config_source"] == "shipped"
    assert d["overruns"] == 1 and d["loop_period_p99_ms"] == 3.3 and d["loop_cycles"] == 2500
    assert d["rms_position_error_m"] == 0.003 and d["odometry_vs_true_max_m"] == 0.002
    assert d["odometry_vs_true_final_m"] == 0.002 and d["error_source"] == "true_pose"
    assert d["emulator_achieved_time_scale"] == 4.9 and d["bus_stray_replies"] == 4
    assert "abort_cause" not in d and "abort_message" not in d and "retried_cycles" not in d
    assert "tracking" not in d and "timing" not in d and "emulator" not in d
    assert json.loads(s.to_json()) == d


def test_a_run_stopped_before_tf_over_4_has_undefined_settled_errors_on_odometry():
    t = tracking_errors(METRICS, "odometry", settled=False)
    assert math.isnan(t.rms_position_error_m) and math.isnan(t.max_position_error_m)
    assert t.final_position_error_m == 0.004 and t.odometry_vs_true_max_m is None
    s = RunSummary("line", "/dev/ttyUSB0", "robot.yaml", "--config", 1.0, False, 10, 4, TIMING,
                   tracking=t, abort_cause="no reply", abort_message="servo ID 7 stopped answering")
    d = s.to_dict()
    assert d["completed"] is False and d["abort_cause"] == "no reply"
    assert "odometry_vs_true_max_m" not in d and "log" not in d and "emulator_lost_sim_s" not in d
