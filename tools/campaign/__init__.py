"""Campaigns: many emulated robots, paths and faults, run on a process pool or on Ray.

``spec`` (the file and its loader), ``draw`` (the robots), ``scenario`` (one run and its row),
``engines`` (pool, Ray), ``store`` (the results folder), ``runner`` (retries, progress),
``report`` (summary.json, summary.md) and ``plots``. The command is ``swerve campaign``.
"""
