"""Run the missing scenarios of a campaign on an engine, keeping each result as it comes.

Keeps at most ``engine.slots`` scenarios outstanding; a scenario whose worker is lost is run
once more, and a second loss makes it a ``failed`` row. A stop signal (Ctrl-C, SIGTERM) closes
the engine and rewrites results.csv from what finished before it propagates; running the same
campaign into the same folder again runs only what is missing.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from .pool import Engine, run_queue
from .scenario import Outcome, base_row, scenario, text
from .store import Store

#: Losses of a scenario's worker before it is a ``failed`` row.
MAX_LOSSES = 2


@dataclass(frozen=True)
class RunStats:
    """What one ``campaign run`` did: scenarios ``ran`` now (``skipped`` were already done),
    ``failures`` among them, ``wall_s`` of the whole run and ``busy_s`` the sum of the
    scenarios' own times on their workers (host-measured)."""

    ran: int
    skipped: int
    failures: int
    wall_s: float
    busy_s: float
    slots: int


def lost_row(store: Store, index: int, reasons: list[str]) -> Outcome:
    """The ``failed`` row of a scenario whose worker was lost :data:`MAX_LOSSES` times."""
    row = base_row(store.campaign, scenario(store.campaign, index))
    row.update(status="failed", reason=f"worker lost {len(reasons)} times: {reasons[-1]}")
    return Outcome(index, {k: text(v) for k, v in row.items()}, 0.0)


def run_missing(store: Store, engine: Engine, progress: bool = True) -> RunStats:
    """Run every scenario of ``store`` not finished yet on ``engine`` (see the module doc)."""
    from tqdm import tqdm

    todo = deque(store.missing())
    total = store.campaign.scenarios
    skipped = total - len(todo)
    failures = ran = 0
    busy_s, t0 = 0.0, time.monotonic()
    bar = tqdm(total=total, initial=skipped, unit="scenario", disable=not progress, dynamic_ncols=True,
               desc=f"{store.campaign.name} ({engine.name}, {engine.slots} at a time)")
    try:
        for done in run_queue(engine, todo):
            if done.outcome is None:
                if store.lose(done.index, done.lost) < MAX_LOSSES:
                    todo.appendleft(done.index)
                    continue
                outcome = lost_row(store, done.index, store.losses[done.index])
            else:
                outcome = done.outcome
            store.add(outcome)
            ran += 1
            busy_s += outcome.run_s
            failures += outcome.status != "completed"
            bar.update(1)
            bar.set_postfix(not_completed=failures, refresh=False)
    finally:
        bar.close()
        engine.close()
        store.write_results()
        store.close()
    return RunStats(ran, skipped, failures, time.monotonic() - t0, busy_s, engine.slots)


__all__ = ["MAX_LOSSES", "RunStats", "lost_row", "run_missing"]
