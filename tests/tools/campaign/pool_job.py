"""A pool job for tests/tools/campaign/test_module_job.py, imported by the pool's workers only."""
from __future__ import annotations

import os

#: How many times this module was imported in this process (0 in the test's own process).
IMPORTS = int(os.environ.get("SWERVE_TEST_POOL_JOB_IMPORTS", "0")) + 1
os.environ["SWERVE_TEST_POOL_JOB_IMPORTS"] = str(IMPORTS)


def run_job(data: str, index: int) -> tuple[str, int, int, int]:
    """``(data, index, worker pid, imports of this module in the worker)``."""
    return data, index, os.getpid(), IMPORTS
