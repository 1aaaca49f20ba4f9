"""The ``swerve`` command: one sub-module per subcommand in :mod:`tools.commands`.

Each module ``tools/commands/<name>.py`` (``export-csv``: ``export_csv.py``) defines
``add_arguments(parser)`` and ``run(args) -> int``, with its imports at its top; a command whose
work imports much keeps ``run`` in a module of its own (:data:`WORK_MODULES`), imported only
once its command line has parsed. The names and
one-line helps of the commands are data here (:data:`COMMANDS`), so ``swerve --help`` lists every
command without importing one, and ``swerve CMD`` imports the module of CMD only.

This module is the one way errors leave the program (:func:`main`):

- a bad option (argparse) or a :class:`~swerve.core.errors.SwerveError` is one line on stderr
  (``swerve CMD: error: ...``) and exit status 2;
- an :class:`OSError` the command did not turn into a ``SwerveError`` is one line naming the
  file and the reason, status 1;
- SIGINT, SIGTERM and SIGHUP stop the command through the same clean-up as Ctrl-C
  (:mod:`swerve.tools.signals`): one line, status 128 + signal number;
- any other exception is a bug: one line naming its type and where it was raised, and the file
  holding the full traceback (``$XDG_STATE_HOME/swerve/``), status 70; ``swerve -v`` prints the
  traceback instead.

Python warnings (NumPy, SciPy, matplotlib) are hidden unless ``-v``; log records of swerve's
own modules at WARNING are printed once each as ``swerve CMD: warning: ...`` (errors are carried
by the exception, so they are not printed twice).
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import logging
import os
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

from swerve.core.errors import SwerveError
from swerve.driver.adapter_latency import ADAPTER_LATENCY_MAX_MS, ADAPTER_LATENCY_MIN_MS
from swerve.emulator.spawn import prestarted
from swerve.tools.argtypes import int_range
from swerve.tools.signals import Interrupted, hold_stop_signals, signals_as_interrupt

#: Every subcommand and its one-line help, in the order ``swerve --help`` lists them.
COMMANDS: dict[str, str] = {
    "emulate": "serve emulated Dynamixel X servos on a pseudo-terminal (prints PORT /dev/pts/N BAUD b IDS ...)",
    "scan": "find Dynamixel servos on a serial port (broadcast ping, then per-ID ping)",
    "doctor": ("check the bus against the robot file: latency timer, IDs and baud, model and firmware, "
                "voltage, temperature, hardware errors, settings, timed read/write cycle. Exit 0: every check "
                "passed or only warned; 1: a check failed"),
    "calibrate": "measure steering zero, wheel direction signs and wheel radius; print or --write them",
    "synth": "synthesise the time-varying LQ gain schedule K(t) of a trajectory (.npz + .dat)",
    "sim": "simulate LQ trajectory tracking on the kinematic model and report tracking errors",
    "run": "track a trajectory on the robot (--port) or on the emulator (--emulate)",
    "demo": "synthesise gains, run the paper's three trajectories on the emulator, write logs, plots, summary",
    "campaign": "run a campaign of emulated scenarios (a process pool or Ray), or replay one of its scenarios",
    "tune": "identify a servo's motor (Levenberg-Marquardt) and design its gains to a step spec",
    "plot": "plot a run log: path, pose, velocities, steering angles, tracking error (PNG)",
    "export-csv": "export a run log (ROS 2 bag) to CSV, one row per control cycle",
    "config": "copy the shipped robot.yaml and emulator.yaml into DIR (default ~/.config/swerve) to edit",
}


def add_config_option(parser: argparse.ArgumentParser) -> None:
    """``--config FILE``: the robot file, the same option in every command that reads one."""
    parser.add_argument("--config", default=None, metavar="FILE",
                        help="robot file (default: $SWERVE_CONFIG, else ~/.config/swerve/robot.yaml, "
                             "else the shipped robot.yaml)")


def add_trajectory_option(parser: argparse.ArgumentParser) -> None:
    """``--trajectory NAME|FILE``: a shipped trajectory or a trajectory file, in every command that tracks one."""
    parser.add_argument("--trajectory", required=True, metavar="NAME|FILE",
                        help="line, circle, curvilinear, a preset, or a .yaml / .csv file "
                             "(formats: docs/trajectories.md)")


def add_bus_options(parser: argparse.ArgumentParser, emulate_help: str) -> None:
    """``--port PORT | --emulate`` and ``--config FILE``: where the servos are, and the robot file."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--port", default=None, help="serial port of the U2D2 (default: link.port in the config)")
    where.add_argument("--emulate", action="store_true", help=emulate_help)
    add_config_option(parser)


def add_adapter_option(parser: argparse.ArgumentParser) -> None:
    """``--adapter-latency-ms MS``: the emulated USB adapter's latency timer (1..255 ms)."""
    parser.add_argument("--adapter-latency-ms", metavar="MS", default=None,
                        type=int_range(ADAPTER_LATENCY_MIN_MS, ADAPTER_LATENCY_MAX_MS),
                        help="the emulated U2D2's USB latency timer, whole ms in 1..255 (16 as shipped, 1 "
                             "once set; default: link.adapter_latency_ms of the robot file)")


#: Commands whose given option means an emulator child will be started (``run --emulate``).
EMULATING_OPTION: dict[str, str] = {"run": "--emulate"}

#: Commands whose work is a module apart from their options: its ``run(args)`` is imported once
#: the command line has parsed, so a bad option is refused before the work's imports (the
#: others' ``run`` is in their command module).
WORK_MODULES: dict[str, str] = {
    "emulate": "swerve.tools.emulate_command",
    "doctor": "swerve.tools.doctor.command",
    "calibrate": "swerve.tools.calibrate_command",
    "campaign": "swerve.tools.campaign.command",
    "tune": "swerve.tools.tune.command",
    "plot": "swerve.tools.plot_command",
}


def starts_emulator(argv: list[str]) -> bool:
    """Whether the command line ``argv`` asks for an emulator child (see :data:`EMULATING_OPTION`)."""
    option = EMULATING_OPTION.get(chosen_command(argv) or "")
    return option is not None and option in argv


def command_module(name: str):
    """The module of the subcommand ``name`` (a key of :data:`COMMANDS`)."""
    return importlib.import_module(f"swerve.tools.commands.{name.replace('-', '_')}")


def work_module(name: str):
    """The module holding ``run(args)`` of the subcommand ``name`` (:data:`WORK_MODULES`, else
    its command module)."""
    return importlib.import_module(WORK_MODULES[name]) if name in WORK_MODULES else command_module(name)


def chosen_command(argv: list[str]) -> str | None:
    """The subcommand ``argv`` names: its first word that is not an option (``None``: none)."""
    return next((a for a in argv if not a.startswith("-")), None)


#: Exit status of a bug (an unexpected exception): EX_SOFTWARE of sysexits.h.
EXIT_BUG = 70
#: Exit status of a user error (a bad option, a SwerveError).
EXIT_USAGE = 2


class OneLineParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose errors are one line: ``PROG: error: MESSAGE``."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(commands=tuple(COMMANDS)) -> argparse.ArgumentParser:
    """The top-level parser: every subcommand is listed; those in ``commands`` (default: all)
    get their options (importing their command modules)."""
    parser = OneLineParser(
        prog="swerve",
        description="Four-wheel steered robot: Dynamixel driver, servo emulator, LQ tracking.")
    parser.add_argument("-v", "--verbose", dest="_verbose", action="store_true",
                        help="show tracebacks, Python warnings and debug logs")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, text in COMMANDS.items():
        p = sub.add_parser(name, help=text, description=text)
        if name in commands:
            command_module(name).add_arguments(p)
    return parser


def crash_dir() -> Path:
    """Where tracebacks of bugs are written: ``$XDG_STATE_HOME/swerve`` (``~/.local/state/swerve``)."""
    base = os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state"
    return Path(base) / "swerve"


def _save_traceback(exc: BaseException, argv: list[str]) -> Path | None:
    """Write the full traceback of ``exc`` to a new file; its path (``None`` if nothing is writable)."""
    text = (f"swerve {' '.join(argv)}\n{time.strftime('%Y-%m-%dT%H:%M:%S%z')}\n\n"
            + "".join(traceback.format_exception(exc)))
    for folder in (crash_dir(), Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(dir=folder, prefix=f"crash-{time.strftime('%Y%m%d-%H%M%S')}-",
                                        suffix=".txt")
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            return Path(name)
        except OSError:
            continue
    return None


def _where(exc: BaseException) -> str:
    """``file.py:LINE in function`` of the frame that raised ``exc``."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return "unknown place"
    f = frames[-1]
    return f"{Path(f.filename).name}:{f.lineno} in {f.name}"


def _one_line(text: str) -> str:
    """``text`` with its lines joined (a message printed by :func:`main` is one line)."""
    return " ".join(part.strip() for part in str(text).splitlines() if part.strip())


class _WarningOnce(logging.Handler):
    """Print swerve's WARNING log records to stderr, one line each, each text once."""

    def __init__(self, prefix: str):
        super().__init__(logging.WARNING)
        self.prefix = prefix
        self.seen: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno >= logging.ERROR:
            return                       # an error travels as the exception main() prints
        text = _one_line(record.getMessage())
        if text not in self.seen:
            self.seen.add(text)
            print(f"{self.prefix}: warning: {text}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _quiet_boundary(verbose: bool, prefix: str):
    """Python warnings hidden and swerve's log records shown once, unless ``verbose``."""
    logger = logging.getLogger("swerve")
    if verbose:
        handler: logging.Handler = logging.StreamHandler(sys.stderr)
        handler.setLevel(logging.DEBUG)
        level = logging.DEBUG
    else:
        handler, level = _WarningOnce(prefix), logging.WARNING
    old_level, old_propagate = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    try:
        with warnings.catch_warnings():
            if not verbose:
                warnings.simplefilter("ignore")
            yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
        logger.propagate = old_propagate


def entry() -> int:
    """The ``swerve`` console script: :func:`main` in a process that exits right after it.

    Before the exit the heap is frozen (``gc.freeze``): the interpreter's finalisation then
    frees objects by their reference counts and leaves the collector's walks of everything the
    command loaded (~0.2 s after ``swerve run``, NumPy, the controller, the log's typestore)
    undone; the memory goes back with the process. The command has closed its files, the
    standard streams are flushed and the ``atexit`` handlers run as before.
    """
    status = main(process_exit=True)
    gc.freeze()
    return status


def main(argv: list[str] | None = None, *, process_exit: bool = False) -> int:
    """Run one ``swerve`` command; returns the exit status (see module doc).

    ``process_exit``: the caller exits right after (the console script), so stop signals that
    arrive after the command's boundary are ignored rather than restored to Python's defaults.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    # an emulator's child interpreter imports on the other CPU while this one imports the command
    with prestarted() if starts_emulator(argv) else contextlib.nullcontext():
        return _run_command(argv, process_exit)


@contextlib.contextmanager
def _imports_uncollected():
    """The cyclic garbage collector off while the command's modules import (and its options
    parse), then what they made frozen (``gc.freeze``: later collections skip it) and the
    collector on again. Imports allocate much and leave almost no cyclic garbage: ~150 young
    collections freed ~300 objects in ``swerve run``'s start. Only in a process that runs one
    command (the console script): frozen objects are never collected."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _run_command(argv: list[str], process_exit: bool) -> int:
    """:func:`main` once the emulator child, if any, was started."""
    with _imports_uncollected() if process_exit else contextlib.nullcontext():
        args = build_parser((chosen_command(argv),)).parse_args(argv)
    verbose = bool(args._verbose or getattr(args, "verbose", False))
    prefix = f"swerve {args.command}"
    with signals_as_interrupt(process_exit), _quiet_boundary(verbose, prefix):
        try:
            return int(work_module(args.command).run(args) or 0)
        except SwerveError as exc:
            hold_stop_signals()
            print(f"{prefix}: error: {_one_line(exc)}", file=sys.stderr)
            return EXIT_USAGE
        except Interrupted as exc:
            hold_stop_signals()
            print(f"{prefix}: stopped by {exc.name}", file=sys.stderr)
            return exc.exit_code
        except KeyboardInterrupt:
            hold_stop_signals()
            print(f"{prefix}: interrupted", file=sys.stderr)
            return 130
        except BrokenPipeError:
            hold_stop_signals()          # the reader of stdout went away: nothing left to say
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 1
        except OSError as exc:
            hold_stop_signals()
            if verbose:
                traceback.print_exc()
            what = f"{exc.filename}: {exc.strerror}" if exc.strerror and exc.filename else (exc.strerror or exc)
            print(f"{prefix}: error: {_one_line(what)}", file=sys.stderr)
            return 1
        except Exception as exc:  # noqa: BLE001 - the boundary: a bug becomes one line and a file
            hold_stop_signals()
            if verbose:
                traceback.print_exc()
                saved = None
            else:
                saved = _save_traceback(exc, argv)
            where = f"{type(exc).__name__} at {_where(exc)}"
            tail = f"; full traceback in {saved}" if saved else ("" if verbose else "; run with -v for the traceback")
            msg = _one_line(exc)
            print(f"{prefix}: internal error (a bug): {where}{': ' + msg if msg else ''}{tail}", file=sys.stderr)
            return EXIT_BUG


if __name__ == "__main__":  # pragma: no cover
    sys.exit(entry())
