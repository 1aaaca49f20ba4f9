"""Any gains file, however malformed, loads as a consistent schedule or is one ControllerError.

Hypothesis builds ``.npz`` and ``.dat`` files from a valid schedule with any part replaced: K of
any shape and type (complex included), phi_rad of any length, Q/R of any shape, meta of any JSON
value, tau_s of any kind, and a ``.npz`` whose header declares an array far larger than memory.
"""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from swerve.controller.errors import ControllerError
from swerve.controller.gains_io import GAINS_MAX_STEPS, load_gains

N = 40
META = {"trajectory": "line", "method": "riccati", "tau_s": 0.016, "cost": 1.0,
        "Q_diag": [1, 1, 1, 1, 1], "R_diag": [1, 1, 1]}


def _npz(path, arrays: dict) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, value in arrays.items():
            buf = io.BytesIO()
            if isinstance(value, tuple):        # (declared shape, dtype): a header and a few bytes
                np.lib.format.write_array_header_1_0(
                    buf, {"descr": np.dtype(value[1]).str, "fortran_order": False, "shape": value[0]})
                buf.write(b"\0" * 64)
            else:
                np.lib.format.write_array(buf, np.asarray(value), allow_pickle=False)
            zf.writestr(f"{name}.npy", buf.getvalue())


def _valid() -> dict:
    rng = np.random.default_rng(0)
    return {"K": rng.normal(size=(N, 3, 5)), "phi_rad": np.zeros(N), "Q": np.eye(5), "R": np.eye(3),
            "meta": json.dumps(META), "times_s": np.arange(N) * 0.016}


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
                     lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=4), c, max_size=3),
                     max_leaves=6)
_shape = st.lists(st.integers(0, 7), min_size=0, max_size=4).map(tuple)
_dtype = st.sampled_from([np.float64, np.float32, np.int32, np.complex128, np.bool_, "U3"])
_part = st.one_of(
    st.tuples(st.just("K"), st.tuples(st.integers(0, 60), st.integers(1, 6), st.integers(1, 6)), _dtype),
    st.tuples(st.sampled_from(["phi_rad", "Q", "R"]), _shape, _dtype),
    st.tuples(st.just("meta"), _json, st.none()),
    st.tuples(st.just("tau_s"), _json | st.sampled_from([0, -1, 1e300, float("nan")]), st.none()),
    st.tuples(st.just("declared"), st.sampled_from(["K", "phi_rad", "Q", "meta"]),
              st.sampled_from([(200_000_000, 3, 5), (GAINS_MAX_STEPS + 1, 3, 5), (2**40,), (1 << 31, 5)])),
    st.tuples(st.just("missing"), st.sampled_from(["K", "phi_rad", "Q", "R", "meta"]), st.none()),
)


def _build(part) -> dict:
    arrays = _valid()
    what, a, b = part
    if what == "meta":
        arrays["meta"] = json.dumps(a)
    elif what == "tau_s":
        arrays["meta"] = json.dumps(dict(META, tau_s=a))
    elif what == "declared":
        arrays[a] = (b, "<f8" if a != "meta" else "<U8")
    elif what == "missing":
        del arrays[a]
    else:
        arrays[what] = np.ones(a, dtype=b) * (1 + 1j if np.dtype(b).kind == "c" else 1) if np.dtype(b).kind != "U" \
            else np.full(a, "abc")
    return arrays


def _dat_text(part) -> str:
    arrays = _build(part) if part[0] in ("meta", "tau_s") else _valid()
    K, phi = arrays["K"], arrays["phi_rad"]
    rows = np.column_stack([np.arange(N) * 0.016, K.reshape(N, 15), phi])
    body = "\n".join(" ".join(f"{v:.6g}" for v in r) for r in rows)
    return f"# swerve gain schedule\n# meta: {arrays['meta']}\n# columns: ...\n{body}\n"


def _check(path) -> None:
    try:
        g = load_gains(path)
    except ControllerError as exc:
        msg = str(exc)
        assert "\n" not in msg and str(path) in msg, msg
        return
    n = g.K.shape[0]
    assert g.K.shape == (n, 3, 5) and g.phi_rad.shape == (n,) and g.Q.shape == (5, 5) and g.R.shape == (3, 3)
    assert all(a.dtype == np.float64 and np.isfinite(a).all() for a in (g.K, g.phi_rad, g.Q, g.R))
    assert g.tau_s > 0 and isinstance(g.meta, dict)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(part=_part)
@example(part=("K", (N, 3, 5), np.complex128))
@example(part=("declared", "K", (200_000_000, 3, 5)))
@example(part=("phi_rad", (2,), np.float64))
@example(part=("meta", [1, 2], None))
def test_any_npz_is_a_schedule_or_one_line(tmp_path, part):
    path = tmp_path / "g.npz"
    _npz(path, _build(part))
    _check(path)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(part=st.tuples(st.sampled_from(["meta", "tau_s"]), _json, st.none()))
@example(part=("meta", [1, 2], None))
def test_any_dat_meta_is_a_schedule_or_one_line(tmp_path, part):
    path = tmp_path / "g.dat"
    path.write_text(_dat_text(part))
    _check(path)


@pytest.mark.parametrize("part, message", [
    (("K", (N, 3, 5), np.complex128), r"K must hold real numbers, got complex128"),
    (("declared", "K", (200_000_000, 3, 5)), r"K must have shape \(N, 3, 5\) with 1 <= N <= 2000000, "
                                             r"got \(200000000, 3, 5\)"),
    (("phi_rad", (2,), np.float64), r"phi_rad must have shape \(40,\) to match K \(40, 3, 5\), got \(2,\)"),
    (("meta", [1, 2], None), r"meta must be a JSON object, got list"),
], ids=["complex", "huge-header", "short-phi", "meta-list"])
def test_the_reported_cases_say_what_is_wrong(tmp_path, part, message):
    path = tmp_path / "g.npz"
    _npz(path, _build(part))
    with pytest.raises(ControllerError, match=message):
        load_gains(path)
