"""``swerve sim``: closed-loop simulation of the tracking law on the nonlinear model (1)-(5)."""
from __future__ import annotations

import json
import sys

import numpy as np

from swerve.configs import locate_robot_file
from swerve.controller.errors import ControllerError
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import load_gains
from swerve.controller.reference import build_reference
from swerve.controller.simulate import metrics, simulate
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import load_trajectory
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_config_option, add_trajectory_option
from swerve.tools.run.geometry import load_robot


#: Largest final position error of a run that converged, m (the paper's trajectories end within mm).
FINAL_ERROR_TOL_M = 0.1


def failure(res, tolerance_m: float) -> str | None:
    """Why a simulated run failed, or ``None``: the reference did not reach its end (the governor
    held it back until the ``1.5 tf`` limit) or the final position error exceeds ``tolerance_m``."""
    tau = float(res.t_s[1] - res.t_s[0]) if len(res.t_s) > 1 else 0.0
    e = res.position_error_m
    if res.ref_time_s[-1] + tau < res.tf_s - 1e-9:
        return (f"the reference stalled: after {res.t_s[-1] + tau:.1f} s (the {res.t_s[-1] / res.tf_s:.1f} tf "
                f"limit) it stands at {res.ref_time_s[-1]:.1f} of {res.tf_s:.1f} s; final position error "
                f"{e[-1]:.3g} m")
    if e[-1] > tolerance_m:
        trend = "grew" if e[-1] > e[0] else "fell"
        return (f"did not converge: final position error {e[-1]:.3g} m > {tolerance_m:g} m (it {trend} from "
                f"{e[0]:.3g} m at the start; largest {e.max():.3g} m)")
    return None


def add_arguments(parser) -> None:
    add_trajectory_option(parser)
    parser.add_argument("--gains", metavar="FILE",
                        help="gain schedule from 'swerve synth' (.npz/.dat); default: "
                             "synthesise with --method now")
    parser.add_argument("--method", choices=("riccati", "paper"), default="riccati",
                        help="synthesis method when --gains is not given (default riccati)")
    parser.add_argument("--law", choices=("rotating", "fixed"), default="rotating",
                        help="rotating chained frames (default) or the paper's fixed frame")
    parser.add_argument("--x0", metavar="x,y,θ,δ1,δ2",
                        help="start state in m and rad (default: the trajectory's)")
    parser.add_argument("--no-governor", action="store_true",
                        help="do not slow the reference while the wheel speed saturates")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--plot", metavar="DIR", help="write PNG figures (paper Figs. 4-9)")
    add_config_option(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--tolerance-m", type=finite_float(0.0, lo_open=True), default=FINAL_ERROR_TOL_M,
                        help="a run whose final position error is larger has failed (exit 1), m "
                             f"(default {FINAL_ERROR_TOL_M})")


def parse_x0(text: str):
    """``--x0 x,y,θ,δ1,δ2`` (m, rad) as an array (5,); a one-line error otherwise."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise ControllerError(f"--x0 must be 5 comma-separated numbers x,y,θ,δ1,δ2, "
                              f"got {text!r}") from None
    if len(vals) != 5 or not np.all(np.isfinite(vals)):
        raise ControllerError(f"--x0 must be 5 finite numbers x,y,θ,δ1,δ2, got {text!r}")
    return np.array(vals)


def run(args) -> int:
    choice = locate_robot_file(args.config)
    geom, limits = load_robot(choice.path)
    traj = load_trajectory(args.trajectory, geom, limits)
    x0 = parse_x0(args.x0) if args.x0 else traj.start_state(geom)
    if args.gains:
        gains = load_gains(args.gains)
        frames = gains.meta.get("frames", args.law)
        if args.law == "fixed" and frames != "fixed":
            raise ControllerError(f"{args.gains} was synthesised for the rotating-frame law; "
                                  "run 'swerve synth --law fixed' for the plain law")
        ref = build_reference(traj, geom, limits, frames)
    else:
        ref, gains = synthesize(traj, args.method, geom, limits, frames=args.law,
                                progress=not args.quiet and sys.stderr.isatty(), start=x0)
    law = TrackingLaw(ref, gains, limits, governor=not args.no_governor)
    res = simulate(law, x0)
    m = metrics(res, traj.Q, traj.R, traj.tau_s)
    if not all(np.isfinite(v) for v in m.values()):
        raise ControllerError(f"simulation of {traj.name!r} produced non-finite values")
    why = failure(res, args.tolerance_m)
    out = dict(trajectory=traj.name, method=gains.method, law=args.law,
               x0=x0.tolist(), synthesis_cost=gains.cost, config=str(choice.path),
               config_source=choice.source, **m, converged=why is None)
    report = getattr(traj.path, "report", None)
    if report is not None:
        out.update(report.as_dict())
    if args.plot:
        from swerve.controller.sim_figures import plot_run

        out["figures"] = [str(p) for p in plot_run(res, ref, gains, args.plot, traj.name)]
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out.items():
            print(f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}")
    if why is not None:
        print(f"swerve sim: failed: {why}", file=sys.stderr)
        return 1
    return 0
