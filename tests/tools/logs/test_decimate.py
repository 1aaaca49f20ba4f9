"""The samples a figure's curve is drawn through (:func:`log_figures.decimate`): over any curve,
with NaN gaps anywhere, the drawn samples keep every bucket's extremes and a gap in every bucket
that has one, and are at most :data:`PLOT_POINTS` plus one per gap."""
from __future__ import annotations

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swerve.tools.logs.log_figures import PLOT_POINTS, decimate

values = st.floats(-1e6, 1e6) | st.just(np.nan)
curves = st.integers(0, 5000).flatmap(lambda n: arrays(np.float64, n, elements=values))


@given(curves, st.sampled_from([4, 10, 101, PLOT_POINTS]))
@example(np.arange(5000.0), PLOT_POINTS)
@example(np.full(3001, np.nan), 100)
@example(np.r_[np.zeros(2000), np.nan, np.ones(2000)], 100)
def test_drawn_samples_keep_each_buckets_extremes_and_gaps(y, points):
    idx = decimate(y, points)
    assert np.all(np.diff(idx) > 0) and (len(idx) == 0 or (idx[0] >= 0 and idx[-1] < len(y)))
    if len(y) <= points:
        assert np.array_equal(idx, np.arange(len(y)))
        return
    size = -(-len(y) // (points // 2))
    kept = set(idx.tolist())
    for start in range(0, len(y), size):
        bucket = y[start:start + size]
        drawn = y[[i for i in range(start, start + len(bucket)) if i in kept]]
        finite = bucket[~np.isnan(bucket)]
        if finite.size:       # the bucket's lowest and highest value are drawn
            assert np.nanmin(drawn) == finite.min() and np.nanmax(drawn) == finite.max()
        if np.isnan(bucket).any():
            assert np.isnan(drawn).any()        # the line breaks there as with every sample
        assert len(drawn) <= 3
    assert len(idx) <= points + int(np.ceil(len(y) / size))


def test_a_spike_of_one_sample_is_drawn():
    y = np.zeros(100_000)
    y[77_777] = 5.0
    idx = decimate(y)
    assert 77_777 in idx and len(idx) <= 2 * PLOT_POINTS
