"""A :class:`ModuleJob` on the pool: the submitting process never imports the job's module, each
worker imports it once and runs every index it gets with it."""
from __future__ import annotations

import sys
from collections import deque

from swerve.tools.campaign.pool import ModuleJob, PoolEngine, run_queue

MODULE = "tests.tools.campaign.pool_job"


def test_workers_import_the_job_once_and_the_parent_never():
    engine = PoolEngine(ModuleJob(MODULE, "data"), 2)
    try:
        done = {d.index: d.outcome for d in run_queue(engine, deque(range(6)))}
    finally:
        engine.close()
    assert MODULE not in sys.modules
    assert sorted(done) == list(range(6))
    assert all(data == "data" and index == i and imports == 1 for i, (data, index, _, imports) in done.items())
    assert 1 <= len({pid for _, _, pid, _ in done.values()}) <= 2      # six jobs, at most two workers
