import json

import numpy as np
import pytest

from swerve.controller.trajectory import TRAJECTORY_DIR
from swerve.tools.cli import main

KEYS = ["rms_position_error_m", "max_position_error_m", "final_position_error_m",
        "max_abs_v1_mps", "max_abs_steer_rate_radps", "cost"]


def test_synth_then_sim_json(tmp_path, capsys):
    out = tmp_path / "line.npz"
    assert main(["synth", "--trajectory", "line", "--out", str(out), "--quiet"]) == 0
    assert out.is_file() and out.with_suffix(".dat").is_file()
    assert "J/J* = 1.0000" in capsys.readouterr().out
    assert main(["sim", "--trajectory", "line", "--gains", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    for k in KEYS:
        assert np.isfinite(data[k])
    # the line's R (positive exponents) corrects the 45-degree start gently: cm, then converged
    assert data["max_position_error_m"] < 0.02 and data["final_position_error_m"] < 1e-4
    assert data["method"] == "riccati"


def test_synth_paper_method(tmp_path, capsys):
    out = tmp_path / "c.npz"
    assert main(["synth", "--trajectory", "circle", "--method", "paper", "--max-iter", "3",
                 "--no-check", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "method: paper" in text and "dai-yuan" in text


def test_sim_plot_and_text(tmp_path, capsys):
    d = tmp_path / "figs"
    assert main(["sim", "--trajectory", str(TRAJECTORY_DIR / "line_neg_x.csv"),
                 "--x0", "0,0.05,2.8,0,0", "--plot", str(d)]) == 0
    text = capsys.readouterr().out
    for k in KEYS:
        assert f"{k}: " in text
    assert sorted(p.name for p in d.iterdir()) == [
        "line_neg_x_gains.png", "line_neg_x_inputs.png", "line_neg_x_path.png",
        "line_neg_x_states.png"]


@pytest.mark.parametrize("argv,match", [
    (["sim", "--trajectory", "circle", "--law", "fixed"], "singular set"),
    (["sim", "--trajectory", "line", "--x0", "0,0,nan,0,0"], "5 finite numbers"),
    (["sim", "--trajectory", "line", "--x0", "0,0,0"], "5 finite numbers"),
    (["sim", "--trajectory", "nowhere"], "unknown trajectory"),
    (["synth", "--trajectory", "line", "--method", "paper", "--beta", "xx"], "unknown beta"),
])
def test_user_errors_are_one_line(argv, match, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_bad_csv_and_mismatched_gains(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text("t,x,y\n0,0,0\n1,0.1,oops\n")
    assert main(["sim", "--trajectory", str(p)]) == 2
    assert "not a number" in capsys.readouterr().err
    out = tmp_path / "line.npz"
    assert main(["synth", "--trajectory", "line", "--out", str(out), "--quiet"]) == 0
    assert main(["sim", "--trajectory", "circle", "--gains", str(out)]) == 2
    assert "does not fit" in capsys.readouterr().err


def test_paper_gains_that_fail_the_check_are_not_written(tmp_path, capsys):
    """The paper as printed, stopped after two CG iterations: gains near K = 0 leave the 45-degree
    start error of the line uncorrected, the check names it and no file is written."""
    out = tmp_path / "bad.npz"
    argv = ["synth", "--trajectory", "line", "--method", "paper", "--init", "zero",
            "--no-precondition", "--initial-errors", "start", "--max-iter", "2",
            "--target-ratio", "0", "--out", str(out), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "gain check 'tracking' fails at t = " in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not out.with_suffix(".dat").exists()
    assert main(argv + ["--no-check"]) == 0           # written on request, for comparison
    assert out.exists()


def test_synth_takes_the_start_state(tmp_path, capsys):
    from swerve.controller.gains_io import load_gains

    out = tmp_path / "l.npz"
    assert main(["synth", "--trajectory", "line", "--x0", "0,0,0", "--out", str(out)]) == 2
    assert "--x0 must be 5 finite numbers" in capsys.readouterr().err
    assert main(["synth", "--trajectory", "line", "--x0", "0.1,0,0.3,0,0", "--out", str(out),
                 "--quiet"]) == 0
    err = load_gains(out).meta["initial_error"]
    assert err[0] == pytest.approx(0.1) and err[4] == pytest.approx(0.0)
