"""``swerve synth``: gain schedule K(t) for a trajectory (Riccati or the paper's CG)."""
from __future__ import annotations

import sys
from pathlib import Path

from swerve.configs import locate_robot_file
from swerve.controller.errors import ControllerError
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import save_gains
from swerve.controller.trajectory import load_trajectory
from swerve.tools.argtypes import finite_float, int_range
from swerve.tools.cli import add_config_option, add_trajectory_option
from swerve.tools.commands.sim import parse_x0
from swerve.tools.run.geometry import load_robot


def add_arguments(parser) -> None:
    add_trajectory_option(parser)
    parser.add_argument("--method", choices=("riccati", "paper"), default="riccati",
                        help="riccati: exact finite-horizon optimum (default); "
                             "paper: nonlinear conjugate gradient (42)-(59)")
    parser.add_argument("--out", metavar="FILE",
                        help="output .npz (a .dat table is written beside it); "
                             "default out/gains/NAME_METHOD.npz")
    parser.add_argument("--law", choices=("rotating", "fixed"), default="rotating",
                        help="chained frame: rotating (re-anchored, default) or fixed "
                             "(the paper's plain chained form)")
    parser.add_argument("--beta", default="dai-yuan",
                        help="paper method: dai-yuan (default), fletcher-reeves, "
                             "polak-ribiere, hestenes-stiefel")
    parser.add_argument("--no-precondition", action="store_true",
                        help="paper method: no block-Hessian preconditioner (with --init zero: "
                             "the paper exactly as printed, slow)")
    parser.add_argument("--initial-errors", choices=("spread", "both", "auto", "start", "basis"),
                        default="spread",
                        help="paper method: the errors J sums over: spread (default: the start "
                             "error and scaled unit errors at t0, and unit errors again every "
                             "second along the horizon), both (start error and unit errors at "
                             "t0), start, basis, or auto (start, or basis when it is zero)")
    parser.add_argument("--init", choices=("frozen-lqr", "continuation", "zero"),
                        default="frozen-lqr",
                        help="paper method: frozen-time LQR gains (default), K = 0 with "
                             "horizon continuation, or K = 0 on the full horizon (as printed)")
    parser.add_argument("--no-check", action="store_true",
                        help="paper method: write the gains even if they fail the check "
                             "(nonlinear closed loop and closed-loop spectrum)")
    parser.add_argument("--target-ratio", type=finite_float(0.0), default=1.001,
                        help="paper method: stop at J <= RATIO * J* (Riccati optimum); "
                             "0 runs until converged or --max-iter (default 1.001)")
    parser.add_argument("--max-iter", type=int_range(1, 1_000_000), default=500, help="paper method: CG iterations")
    parser.add_argument("--x0", metavar="x,y,θ,δ1,δ2",
                        help="robot start state in m and rad (default: the trajectory's); its "
                             "error is part of the paper method's cost and of its check")
    add_config_option(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    choice = locate_robot_file(args.config)
    geom, limits = load_robot(choice.path)
    traj = load_trajectory(args.trajectory, geom, limits)
    start = parse_x0(args.x0) if args.x0 else None
    if args.max_iter < 1:
        raise ControllerError("--max-iter must be at least 1")
    ref, gains = synthesize(traj, args.method, geom, limits, frames=args.law, beta=args.beta,
                            precondition=not args.no_precondition,
                            initial_errors=args.initial_errors, max_iter=args.max_iter,
                            init=args.init, target_ratio=args.target_ratio,
                            progress=not args.quiet and sys.stderr.isatty(),
                            check=not args.no_check, start=start)
    out = Path(args.out) if args.out else Path("out/gains") / f"{traj.name}_{args.method}.npz"
    if out.suffix != ".npz":
        raise ControllerError(f"--out must end in .npz, got {out}")
    save_gains(out, gains)
    dat = save_gains(out.with_suffix(".dat"), gains)
    m = gains.meta
    print(f"config: {choice.describe()}")
    print(f"trajectory: {traj.name}  (N = {traj.n_steps}, tau = {traj.tau_s} s, "
          f"tf = {traj.tf_s:g} s, frames = {args.law}, "
          f"{len(set(gains.phi_rad.round(9)))} chained frame(s))")
    print(f"method: {args.method}  cost J = {gains.cost:.6g}  J* = {m['J_star']:.6g}"
          + (f"  J/J* = {gains.cost / m['J_star']:.4f}" if m["J_star"] > 0 else ""))
    if args.method == "paper":
        print(f"CG ({m['beta']}{', preconditioned' if m['precondition'] else ''}, "
              f"init {m['init']}): "
              f"{m['iterations']} iterations, {m['evaluations']} evaluations, "
              f"{m['seconds']:.2f} s: {m['message']}")
    print(f"wrote {out} and {dat}")
    return 0
