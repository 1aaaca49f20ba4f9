"""Run logs of the tracking loop: record, write (ROS 2 bag, MCAP), read back, export, plot.

The 62.5 Hz loop builds one :class:`CycleRecord` per cycle and hands it to
:meth:`RunLogWriter.write`; ``swerve export-csv`` and ``swerve plot`` read the bag back with
:func:`read_log`. Format: ``tools/logs/README.md``.
"""
from .bag import RunLog, RunLogWriter, read_log, repair_log
from .record import CYCLE_FIELDS, CycleFlag, CycleRecord

__all__ = ["CYCLE_FIELDS", "CycleFlag", "CycleRecord", "RunLog", "RunLogWriter", "read_log",
           "repair_log", "export_csv", "plot_run"]


def export_csv(log, out_path):
    """See :func:`tools.logs.csv_export.export_csv` (imported lazily)."""
    from .csv_export import export_csv as _export

    return _export(log, out_path)


def plot_run(log, out_dir, sim=None):
    """See :func:`tools.logs.log_figures.plot_run` (imported lazily: matplotlib is slow to import)."""
    from .log_figures import plot_run as _plot

    return _plot(log, out_dir, sim=sim)
