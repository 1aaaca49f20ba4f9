"""Trajectory tracking for the four-wheel independently steered robot.

Everything between a desired path and the wheel commands, offline and online, after
Ćaran et al., *Actuators* 2024, 13, 279 (see ``controller/README.md``). SI units throughout;
state ``s = (x_m, y_m, theta_rad, delta1_rad, delta2_rad)``, inputs
``(v1_mps, omega1_radps, omega2_radps)``.

Public API
----------
Robot data: plain numbers (the robot file becomes them in :mod:`swerve.tools.run.geometry`)::

    geom = controller.kinematics.Geometry(a_m, b_m, wheel_radius_m)
    limits = controller.kinematics.Limits(v1_max_mps, steer_rate_max_radps, steer_angle_max_rad)

Offline (``swerve synth``)::

    traj = controller.trajectory.load_trajectory("circle")     # or "line", "curvilinear",
                                                               # a .yaml or a t,x,y .csv file
    ref, gains = controller.gain_schedule.synthesize(traj, "riccati", geom, limits)   # or "paper"
    controller.gains_io.save_gains("circle.npz", gains)        # also ".dat" (62.5 Hz table)
    gains = controller.gains_io.load_gains("circle.npz")

Online, at 62.5 Hz on the robot (``swerve sim`` runs exactly this law)::

    ref = controller.reference.build_reference(traj, geom, limits)   # frames must match gains
    law = controller.tracking.TrackingLaw(ref, gains, limits)
    law.reset()
    x0 = ref.start_state()                                      # == traj.start_state(geom)
    out = law.step(t_s, state)                                  # LawOutput; state: shape (5,)
    out.v1_mps, out.omega1_radps, out.delta1_rad, out.error     # inputs, goals, diagnostics
    goals = out.wheel_goals                                     # [v1]*4 + [d1, d2, d2, d1]
    controller.kinematics.wheel_commands(v1, d1, d2)            # the same 8-vector by hand
    controller.kinematics.drive_angular_speed(v1, geom.wheel_radius_m)   # rad/s at the wheel

Modules: :mod:`.kinematics` model (1)-(5); :mod:`.chained` chained form (6)-(18) in a rotated
frame; :mod:`.paths` line/circle/curvilinear paths and drawn samples; :mod:`.path_csv` reading and
checking drawn CSV files; :mod:`.path_segments` lines and arcs in samples; :mod:`.path_fit` the
drawn-path fit; :mod:`.trajectory` trajectory files; :mod:`.reference` desired states and frame
schedule; :mod:`.ltv` LTV error system and cost; :mod:`.riccati`
finite-horizon Riccati; :mod:`.synthesis` the paper's conjugate-gradient method;
:mod:`.gain_schedule` both in one call; :mod:`.gains_io` schedule files; :mod:`.tracking` the online
law; :mod:`.simulate` closed loop on model (1)-(5); :mod:`.plots` figures like the paper's 4-9;
:mod:`.errors` :class:`ControllerError` (a ``ConfigError``: one-line CLI errors). The online
loop that runs the law on the robot is the application layer's (:mod:`swerve.tools.run`); this
package imports nothing from the driver, the emulator or the tools.

Sign convention: ``u = ud + K (x - xd)`` (the paper writes ``ud - K x~``).
"""
