"""Run logs of the tracking loop: record, write (ROS 2 bag, MCAP), read back, export, plot.

The 62.5 Hz loop builds one :class:`CycleRecord` per cycle and hands it to
:meth:`RunLogWriter.write`; ``swerve export-csv`` and ``swerve plot`` read the bag back with
:func:`read_log`; :mod:`.csv_export` and :mod:`.log_figures` (matplotlib) turn a log into a CSV
file and figures. Format: ``tools/logs/README.md``.
"""
from .bag import RunLog, RunLogWriter, read_log, repair_log
from .record import CYCLE_FIELDS, CycleFlag, CycleRecord

__all__ = ["CYCLE_FIELDS", "CycleFlag", "CycleRecord", "RunLog", "RunLogWriter", "read_log", "repair_log"]
