"""CSV export, plots and the two CLI commands, including their user errors."""
import csv

import pytest

from swerve.tools.cli import main
from swerve.tools.logs import RunLogWriter, read_log
from swerve.tools.logs.csv_export import export_csv
from swerve.tools.logs.log_figures import plot_run
from swerve.tools.logs.record import CYCLE_SIZE


def test_csv_has_one_row_per_cycle_and_units(run_bag, run_records, tmp_path):
    out = export_csv(read_log(run_bag), tmp_path / "run.csv")
    rows = list(csv.reader(out.open()))
    header, body = rows[0], rows[1:]
    assert len(body) == 500 and len(header) == CYCLE_SIZE + 1
    assert header[:3] == ["stamp_ns [ns]", "t_s [s]", "cycle [1]"]
    assert "est_pose_theta [rad]" in header and "meas_current_a_8 [A]" in header
    col = header.index("est_pose_x [m]")
    assert float(body[42][col]) == run_records[42].est_pose[0]
    assert int(body[42][0]) == run_records[42].stamp_ns
    assert body[0][header.index("sim_pose_x [m]")] == "nan"


def test_plots_are_written(run_bag, tmp_path):
    paths = plot_run(read_log(run_bag), tmp_path / "figs")
    assert {p.name for p in paths} >= {"path.png", "pose.png", "velocities.png", "steering.png", "error.png"}
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000


def test_cli_export_default_path_and_plot(run_bag, tmp_path, capsys):
    assert main(["export-csv", str(run_bag)]) == 0
    assert run_bag.with_name(run_bag.name + ".csv").exists()
    assert main(["plot", str(run_bag), "--out", str(tmp_path / "p"), "--sim", str(run_bag)]) == 0
    assert len(list((tmp_path / "p").glob("*.png"))) == 6


def _empty_log(path):
    with RunLogWriter(path, {}):
        pass
    return path


def _foreign_bag(path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        w.write(c, 1, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
    return path


@pytest.mark.parametrize("make, message", [
    (lambda p: p / "missing", "no such run log"),
    (lambda p: (p / "junk.mcap").write_bytes(b"\x00" * 300) and p / "junk.mcap", "not a swerve run log"),
    (lambda p: (p / "d").mkdir() or p / "d", "holds 0 .mcap files"),
    (lambda p: _foreign_bag(p / "other"), "no /swerve/cycle"),
    (lambda p: _empty_log(p / "empty"), "empty run log"),
], ids=["missing", "garbage", "empty-dir", "foreign-bag", "no-cycles"])
@pytest.mark.parametrize("command", ["export-csv", "plot"])
def test_cli_user_errors_are_one_line(tmp_path, capsys, make, message, command):
    path = make(tmp_path)
    argv = [command, str(path)] + (["--out", str(tmp_path / "o")] if command == "plot" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1
