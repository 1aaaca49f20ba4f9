"""Levenberg–Marquardt identification of the servo's DC motor from open-loop PWM steps.

Model (motor side, :func:`emulator.physics.motor.state_space`)::

    L di/dt = v - R i - Ke w          J dw/dt = Km i - b w          dtheta/dt = w,   theta_out = theta / N

with ``v = duty * V_supply`` piecewise constant between Goal PWM writes. Measured: Present Position
(encoder pulses, floor-quantised) and Present Current (2.69 mA LSB, rounded), at irregular bus
sample times.

What the data can and cannot separate (README "Identifiability"):

- ``R`` (from the current right after a step, ``v/R``) and ``Ke`` (from the steady speed and
  current, ``v = R i + Ke N w_out``) are identified, given the gear ratio ``N`` of the model.
- ``Km``, ``J`` and ``b`` enter only as ``Km/J`` and ``b/J``: scaling all three by one factor gives
  identical responses, because no known torque acts on the shaft. ``Km`` is therefore fixed at
  its prior and ``J``, ``b`` are reported *relative to that prior* (exact if the prior is right).
- ``L``: the electrical time constant ``L/R`` (~0.3 ms) is below the bus sampling interval
  (~1-3 ms); the data barely constrain it, so it is fixed at its prior.

The fit is exact in time: each sample is evaluated with the closed-form solution of the linear
ODE between input switches (eigen-decomposition), so irregular sample times need no resampling.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import brentq, least_squares

from swerve.emulator.physics.motor import state_space
from swerve.emulator.physics.params import MotorParams

FITTED = ("resistance_ohm", "back_emf_v_s_per_rad", "inertia_kg_m2", "friction_nm_s_per_rad")
FIXED_REASONS = {
    "inductance_h": "electrical time constant L/R ~0.3 ms is far below the bus sampling interval",
    "torque_nm_per_a": "only Km/J and b/J are observable without a known load torque; "
                       "J and b are reported relative to this Km",
}
#: Output-side Coulomb friction, fitted in units of this torque (N m) so its step is O(1).
COULOMB_SCALE_NM = 0.01
UNITS = {"coulomb_nm": "N m", "resistance_ohm": "ohm", "back_emf_v_s_per_rad": "V s/rad", "inertia_kg_m2": "kg m^2",
         "friction_nm_s_per_rad": "N m s/rad", "inductance_h": "H", "torque_nm_per_a": "N m/A"}
Z95 = 1.959963984540054
#: Floor of the switch-time prior, s: wide enough for a write that took effect later than the
#: samples around it suggest (a retried or late reply); the current spikes pin it down.
SWITCH_STD_MIN_S = 0.01


@dataclass(frozen=True)
class PwmRecord:
    """One open-loop experiment: piecewise-constant armature voltage and the sampled response.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Sample times, s, on the servo's clock, from the record start.
    position_rad : ndarray, shape (n,)
        Present Position, output-shaft rad (an integer number of encoder LSBs).
    current_a : ndarray, shape (n,)
        Present Current, A.
    switch_t_s : ndarray, shape (m,)
        Times at which each Goal PWM write was sent, s (same clock as ``t_s``).
    voltage_v : ndarray, shape (m,)
        Armature voltage from each switch on (duty times supply voltage), V. Before the first
        switch the voltage is 0 and the motor is at rest.
    switch_std_s : ndarray, shape (m,), optional
        Uncertainty of each switch time, s (e.g. half the gap between the samples around the
        write). Each switch time is fitted within it (a Gaussian prior); default 1 ms.
    """

    t_s: np.ndarray
    position_rad: np.ndarray
    current_a: np.ndarray
    switch_t_s: np.ndarray
    voltage_v: np.ndarray
    switch_std_s: np.ndarray | None = None

    def switch_std(self) -> np.ndarray:
        """Switch-time uncertainties, s, shape (m,)."""
        if self.switch_std_s is None:
            return np.full(self.switch_t_s.shape, SWITCH_STD_MIN_S)
        return np.maximum(np.asarray(self.switch_std_s, float), SWITCH_STD_MIN_S)


@dataclass(frozen=True)
class Estimate:
    """One parameter: value with a 95 % confidence interval (``nan`` if fixed)."""

    value: float
    ci_low: float
    ci_high: float
    unit: str
    identified: bool
    note: str = ""

    @property
    def rel_halfwidth(self) -> float:
        """Half the 95 % interval relative to the value (``nan`` if fixed)."""
        return 0.5 * (self.ci_high - self.ci_low) / self.value if self.identified else float("nan")


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`.

    Attributes
    ----------
    params : MotorParams
        Identified values with the non-identifiable ones at their priors.
    gear_ratio : float
        Gear ratio used (from the servo model), motor turns per output turn.
    estimates : dict[str, Estimate]
        Every motor parameter, identified or fixed.
    derived : dict[str, float]
        Combinations the data determine directly: mechanical time constant ``tau_m_s``,
        ``km_over_j`` (1/(A s^2)), ``b_over_km`` (A s/rad), no-load output speed at 12 V.
    delay_s : float
        Mean fitted shift of the switch times from where the current jumps put them, s.
    position_skew_s : float
        Fitted age of Present Position relative to Present Current in one read, s (the
        emulator samples the encoder one physics tick before the current).
    residual_rms : dict[str, float]
        RMS fit residual: ``position_pulse`` (LSB) and ``current_a`` (A).
    noise_std : dict[str, float]
        Sample standard deviation at rest (``position_pulse``, ``current_a``) used as weights.
    correlation : ndarray, shape (k, k)
        Correlation of the fitted parameters (log scale for the motor constants), in
        :data:`FITTED` order, then ``coulomb_nm`` if it was fitted (k = 5).
    n_samples : int
        Samples used (both channels count once per bus read).
    switch_t_s : list[ndarray]
        Fitted switch times of each record, s (shape (m,) each).
    """

    params: MotorParams
    gear_ratio: float
    estimates: dict[str, Estimate]
    derived: dict[str, float]
    delay_s: float
    position_skew_s: float
    residual_rms: dict[str, float]
    noise_std: dict[str, float]
    correlation: np.ndarray
    n_samples: int
    extra: dict = field(default_factory=dict)
    switch_t_s: list = field(default_factory=list, repr=False)
    coulomb_nm: float = 0.0
    """Fitted Coulomb friction at the output shaft, N m (0 if not fitted)."""


def simulate_open_loop(params: MotorParams, gear_ratio: float, t_s: np.ndarray,
                       switch_t_s: np.ndarray, voltage_v: np.ndarray,
                       coulomb_nm: float = 0.0) -> dict[str, np.ndarray]:
    """Exact response of the geared motor, from rest, to a piecewise-constant voltage.

    With ``coulomb_nm > 0`` a Coulomb torque ``sign(w) Tc`` at the output opposes the motion:
    the shaft stops where its speed reaches zero and stays stuck until the motor torque exceeds
    ``Tc`` (static = Coulomb; the Stribeck rise below ~1.5 rad/s is not modelled). While stuck only
    the current moves (``L di/dt = v - R i``). Between events the ODE is linear with a constant
    input, so every phase is solved in closed form; the zero crossing is found with ``brentq``.

    Parameters
    ----------
    params : MotorParams
        Motor-side constants.
    gear_ratio : float
        Motor turns per output turn.
    t_s : ndarray, shape (n,)
        Sample times, s (any order).
    switch_t_s, voltage_v : ndarray, shape (m,)
        The voltage is 0 before ``switch_t_s[0]`` and ``voltage_v[k]`` from ``switch_t_s[k]``.
    coulomb_nm : float
        Coulomb friction torque at the output shaft, N m (a negative value aids the motion; it
        keeps the fit's parameter space continuous through 0).

    Returns
    -------
    dict
        ``angle_rad``, ``speed_radps`` (output shaft, from the start angle 0) and ``current_a``,
        each shape (n,).
    """
    t_s = np.asarray(t_s, float)
    a3, b3 = state_space(params, params.inertia_kg_m2)
    motor = _Linear(a3[:2, :2], b3[:2, 0], b3[:2, 1])
    r, l, km = params.resistance_ohm, params.inductance_h, params.torque_nm_per_a
    tc = coulomb_nm / gear_ratio                      # motor side, N m
    bounds = np.concatenate([[-np.inf], np.asarray(switch_t_s, float), [np.inf]])
    volts = np.concatenate([[0.0], np.asarray(voltage_v, float)])
    z = np.zeros(2)                                   # [i, w] at the phase start
    theta = 0.0
    out = np.zeros((3, t_s.size))
    first, last = (float(t_s.min()), float(t_s.max())) if t_s.size else (0.0, 0.0)
    for k in range(volts.size):
        t0 = bounds[k] if np.isfinite(bounds[k]) else min(0.0, first)
        t_end = bounds[k + 1] if np.isfinite(bounds[k + 1]) else max(last, t0) + 1.0
        v = volts[k]
        while True:
            stuck = z[1] == 0.0 and tc > 0.0
            if stuck:                                 # w = 0: only the current evolves
                i_ss = v / r
                start = np.inf
                if np.sign(v) * km * z[0] >= tc:      # already driving hard enough
                    start = 0.0
                elif abs(km * i_ss) > tc:             # breaks loose when |Km i| reaches Tc
                    start = -l / r * np.log((np.sign(v) * tc / km - i_ss) / (z[0] - i_ss))
                t_next = min(t0 + start, t_end)
                sel = (t_s >= t0) & (t_s < t_next)
                tau = t_s[sel] - t0
                out[0, sel], out[1, sel] = theta, 0.0
                out[2, sel] = i_ss + (z[0] - i_ss) * np.exp(-r / l * tau)
                z = np.array([i_ss + (z[0] - i_ss) * np.exp(-r / l * (t_next - t0)), 0.0])
                if t_next >= t_end:
                    break
                t0, direction = t_next, np.sign(v)
            else:
                direction = np.sign(z[1]) if z[1] != 0.0 else np.sign(v)
            sol = motor.from_state(z, theta, v, direction * tc)
            t_next = t_end
            if tc > 0.0 and direction != 0.0 and direction * sol.speed(t_end - t0) < 0.0:
                t_next = t0 + brentq(sol.speed, 0.0, t_end - t0, xtol=1e-9)
            sel = (t_s >= t0) & (t_s < t_next)
            zt, th = sol(t_s[sel] - t0)
            out[0, sel], out[1, sel], out[2, sel] = th, zt[:, 1], zt[:, 0]
            zt, th = sol(np.array([t_next - t0]))
            z, theta = zt[0].copy(), float(th[0])
            if t_next >= t_end:
                break
            z[1], t0 = 0.0, t_next                    # the speed reached zero: stuck from here
    return {"angle_rad": out[0] / gear_ratio, "speed_radps": out[1] / gear_ratio,
            "current_a": out[2]}


class _Linear:
    """Closed-form solution of ``dz/dt = A z + bv v + bt tau`` (z = [i, w]) and of the angle."""

    def __init__(self, a: np.ndarray, bv: np.ndarray, bt: np.ndarray):
        self.lam, self.vec = np.linalg.eig(a)
        self.vinv = np.linalg.inv(self.vec)
        self.a_inv_bv, self.a_inv_bt = np.linalg.solve(a, bv), np.linalg.solve(a, bt)

    def from_state(self, z0: np.ndarray, theta0: float, v: float, tau: float) -> "_Phase":
        z_ss = -self.a_inv_bv * v - self.a_inv_bt * tau
        return _Phase(self, z_ss, self.vinv @ (z0 - z_ss), theta0)


class _Phase:
    """One constant-input phase: ``(z (n, 2), theta (n,))`` at times ``tau`` after its start."""

    def __init__(self, lin: _Linear, z_ss: np.ndarray, c: np.ndarray, theta0: float):
        self.lin, self.z_ss, self.c, self.theta0 = lin, z_ss, c, theta0

    def __call__(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lam, vec, c = self.lin.lam, self.lin.vec, self.c
        e = np.exp(np.outer(tau, lam))                 # (n, 2)
        zt = (self.z_ss[None, :] + (e * c[None, :]) @ vec.T).real
        th = self.theta0 + self.z_ss[1] * tau + (((e - 1.0) / lam[None, :] * c[None, :]) @ vec[1, :]).real
        return zt, th

    def speed(self, tau: float) -> float:
        """Motor speed ``tau`` s after the phase start, rad/s."""
        return float((self.z_ss[1] + (np.exp(self.lin.lam * tau) * self.c) @ self.lin.vec[1, :]).real)


def _rest_samples(rec: PwmRecord, lsb: float, signal: np.ndarray) -> np.ndarray:
    """Samples taken before the first switch (motor at rest), in LSB, about their mean."""
    rest = signal[rec.t_s < rec.switch_t_s[0]] / lsb
    return rest - rest.mean()


def locate_switches(rec: PwmRecord, noise_a: float) -> PwmRecord:
    """Re-time each voltage switch from the current jump it causes.

    A step ``dv`` in armature voltage moves the current by about ``dv / R`` within ``L/R``
    (~0.3 ms), far above the sensor noise. Around each logged switch (between the midpoints to its
    neighbours) the pair of consecutive samples with the largest current change in the sign of
    ``dv`` brackets the switch; its midpoint and half-width become the switch time and its
    uncertainty. A switch whose jump is not clearly (> 6 noise std) visible keeps its logged time.
    This guards against write times that a late or retried bus reply has put in the wrong place.

    Parameters
    ----------
    rec : PwmRecord
        Record with logged switch times.
    noise_a : float
        Current noise standard deviation, A.

    Returns
    -------
    PwmRecord
        A copy with ``switch_t_s`` and ``switch_std_s`` from the data where possible.
    """
    sw = np.asarray(rec.switch_t_s, float).copy()
    std = rec.switch_std().copy()
    dv = np.diff(np.concatenate([[0.0], rec.voltage_v]))
    edges = np.concatenate([[-np.inf], 0.5 * (sw[1:] + sw[:-1]), [np.inf]])
    di = np.diff(rec.current_a)
    for k in range(sw.size):
        if dv[k] == 0.0:
            continue
        j = np.nonzero((rec.t_s[1:] > edges[k]) & (rec.t_s[:-1] < edges[k + 1]))[0]
        if j.size == 0:
            continue
        best = j[np.argmax(np.sign(dv[k]) * di[j])]
        if np.sign(dv[k]) * di[best] > 6.0 * max(noise_a, 1e-6) * np.sqrt(2.0):
            t0, t1 = rec.t_s[best], rec.t_s[best + 1]
            sw[k], std[k] = 0.5 * (t0 + t1), 0.5 * (t1 - t0)
    return replace(rec, switch_t_s=sw, switch_std_s=std)


def identify(records: list[PwmRecord], gear_ratio: float, prior: MotorParams, *,
             position_lsb_rad: float, current_lsb_a: float, coulomb: bool = True) -> Identification:
    """Fit ``R, Ke, J, b`` and the output's Coulomb friction ``Tc`` (plus per-switch time shifts, a
    position/current time skew and per-record angle offsets as nuisance parameters) with
    Levenberg–Marquardt.

    ``Tc`` shows as the current the motor needs to keep turning at any speed, ``Tc / (N Km)``,
    and as the shaft stopping in finite time when braked; the ±duty steps at two amplitudes
    separate it from the viscous ``b`` (whose torque grows with speed).

    Parameters
    ----------
    records : list[PwmRecord]
        Open-loop PWM experiments, each starting at rest with at least a few rest samples.
    gear_ratio : float
        Gear ratio of the servo model (not fitted: only ``Ke * N`` would be observable).
    prior : MotorParams
        Start values; ``inductance_h`` and ``torque_nm_per_a`` are kept fixed at these.
    position_lsb_rad, current_lsb_a : float
        Encoder and current quantisation steps (output rad per pulse; A per LSB).
    coulomb : bool
        Fit the Coulomb friction; ``False`` keeps it at 0 (viscous friction only).

    Returns
    -------
    Identification

    Raises
    ------
    ValueError
        If a record has no rest samples or no switch.
    """
    for rec in records:
        if rec.switch_t_s.size == 0 or not np.any(rec.t_s < rec.switch_t_s[0]):
            raise ValueError("each PWM record needs rest samples before its first switch")
    # Weights: quantisation (uniform, variance 1/12 LSB^2) plus the noise seen at rest.
    pos_rest = np.concatenate([_rest_samples(r, position_lsb_rad, r.position_rad) for r in records])
    cur_rest = np.concatenate([_rest_samples(r, current_lsb_a, r.current_a) for r in records])
    sig_p = np.sqrt(1.0 / 12.0 + np.var(pos_rest))          # pulses
    sig_i = np.sqrt(1.0 / 12.0 + np.var(cur_rest))          # current LSBs
    records = [locate_switches(r, sig_i * current_lsb_a) for r in records]
    n_sw = [r.switch_t_s.size for r in records]
    n_head = 6 if coulomb else 5                    # log R, Ke, J, b; skew; [Tc / scale]
    x0 = np.concatenate([np.log([getattr(prior, n) for n in FITTED]), [0.0], [0.0] * (n_head - 5),
                         np.zeros(sum(n_sw)),
                         [np.mean(r.position_rad[r.t_s < r.switch_t_s[0]]) / position_lsb_rad + 0.5
                          for r in records]])
    n_fit = n_head + sum(n_sw)

    def unpack(x):
        shifts = np.split(x[n_head:n_fit], np.cumsum(n_sw)[:-1])
        tc = x[5] * COULOMB_SCALE_NM if coulomb else 0.0
        return replace(prior, **dict(zip(FITTED, np.exp(x[:4])))), x[4], tc, shifts, x[n_fit:]

    def residuals(x):
        p, skew, tc, shifts, offsets = unpack(x)
        res = []
        for rec, shift, off in zip(records, shifts, offsets):
            n = rec.t_s.size
            sim = simulate_open_loop(p, gear_ratio, np.concatenate([rec.t_s - skew, rec.t_s]),
                                     rec.switch_t_s + shift, rec.voltage_v, tc)
            res.append((sim["angle_rad"][:n] / position_lsb_rad + off - 0.5
                        - rec.position_rad / position_lsb_rad) / sig_p)
            res.append((sim["current_a"][n:] - rec.current_a) / current_lsb_a / sig_i)
            res.append(shift / rec.switch_std())
        return np.concatenate(res)

    sol = least_squares(residuals, x0, method="lm", x_scale="jac")
    p, skew, tc, shifts, _ = unpack(sol.x)
    delay = float(np.mean(np.concatenate(shifts)))
    m, k = sol.fun.size - sum(n_sw), sol.x.size - sum(n_sw)    # the switch priors are not data
    r_pos = np.concatenate([sol.fun[a:a + n] for a, n in _channel_slices(records, 0)]) * sig_p
    r_cur = np.concatenate([sol.fun[a:a + n] for a, n in _channel_slices(records, 1)]) * sig_i
    s2 = float(np.sum(r_pos ** 2) / sig_p ** 2 + np.sum(r_cur ** 2) / sig_i ** 2) / max(m - k, 1)
    jac = sol.jac
    cov = np.linalg.pinv(jac.T @ jac) * max(s2, 1.0)     # never claim more than the noise allows
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    est = {}
    for j, name in enumerate(FITTED):
        v = getattr(p, name)
        est[name] = Estimate(v, v * np.exp(-Z95 * std[j]), v * np.exp(Z95 * std[j]), UNITS[name], True,
                             "relative to the fixed Km" if name in ("inertia_kg_m2", "friction_nm_s_per_rad")
                             else "")
    for name, why in FIXED_REASONS.items():
        est[name] = Estimate(getattr(p, name), float("nan"), float("nan"), UNITS[name], False, why)
    if coulomb:
        sd = std[5] * COULOMB_SCALE_NM
        est["coulomb_nm"] = Estimate(tc, tc - Z95 * sd, tc + Z95 * sd, UNITS["coulomb_nm"], True,
                                     "output shaft; static friction taken equal")
    keep = list(range(4)) + ([5] if coulomb else [])
    sub = cov[np.ix_(keep, keep)]
    d = np.sqrt(np.clip(np.diag(sub), 1e-300, None))
    corr = sub / np.outer(d, d)
    return Identification(
        params=p, gear_ratio=gear_ratio, estimates=est, derived=derived_quantities(p, gear_ratio),
        delay_s=float(delay), position_skew_s=float(skew),
        residual_rms={"position_pulse": float(np.sqrt(np.mean(r_pos ** 2))),
                      "current_a": float(np.sqrt(np.mean(r_cur ** 2))) * current_lsb_a},
        noise_std={"position_pulse": float(np.std(pos_rest)), "current_a": float(np.std(cur_rest)) * current_lsb_a},
        correlation=corr, n_samples=int(sum(r.t_s.size for r in records)),
        extra={"nfev": int(sol.nfev), "status": int(sol.status), "reduced_chi2": float(s2)},
        switch_t_s=[r.switch_t_s + sh for r, sh in zip(records, shifts)], coulomb_nm=float(tc))


def _channel_slices(records: list[PwmRecord], channel: int) -> list[tuple[int, int]]:
    """``(start, length)`` of each record's position (0) or current (1) residuals."""
    out, start = [], 0
    for rec in records:
        n = rec.t_s.size
        out.append((start + channel * n, n))
        start += 2 * n + rec.switch_t_s.size
    return out


def derived_quantities(p: MotorParams, gear_ratio: float, supply_v: float = 12.0) -> dict[str, float]:
    """Combinations of the motor constants that the step data determine directly.

    Returns
    -------
    dict
        ``tau_m_s`` mechanical time constant ``J R / (R b + Ke Km)``; ``km_over_j`` (1/(A s^2));
        ``b_over_km`` (A s/rad); ``no_load_speed_out_radps`` at ``supply_v``.
    """
    r, ke, km, b, j = (p.resistance_ohm, p.back_emf_v_s_per_rad, p.torque_nm_per_a,
                       p.friction_nm_s_per_rad, p.inertia_kg_m2)
    return {"tau_m_s": j * r / (r * b + ke * km), "km_over_j": km / j, "b_over_km": b / km,
            "no_load_speed_out_radps": supply_v * km / (r * b + ke * km) / gear_ratio}
