"""``swerve`` commands in processes forked from one interpreter that has imported swerve once.

A test that runs many short commands (most of them refused within milliseconds) spends most of
each fresh ``python -m swerve.tools.cli`` on the interpreter's start and the imports: ~0.7 s of
CPU per command. :class:`CommandServer` starts one server process (this file run as a script)
that imports :mod:`swerve.tools.cli` and every command's option and work module, then forks one
child per command. The child runs the console script's function (:func:`swerve.tools.cli.entry`)
as ``python -m swerve.tools.cli`` does, with its standard input on ``/dev/null`` and its
standard output and error in files, and exits with the command's status as the interpreter
would (``SystemExit`` codes as Python maps them, the ``atexit`` handlers run).

What the fork does not repeat is the start-up itself: the server's imports are checked once to
print nothing (:attr:`CommandServer.import_output`), since a fresh command would print the same
on every run. The server's working directory and environment are the children's.

Protocol (one JSON object a line): the client sends ``{"argv": [...], "out": PREFIX, "cwd": DIR,
"env": {NAME: VALUE}}`` (``cwd`` and ``env``: the command's working directory and the variables
it sets on the server's environment, read by the command when it runs, not when it imports); the
server answers ``{"pid": N}`` once the child is forked, then ``{"status": S}`` when it ended
(``S`` as :attr:`subprocess.CompletedProcess.returncode`: negative for a signal).
"""
from __future__ import annotations

import atexit
import json
import os
import select
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Finished:
    """What a forked command left: its exit status, standard output and standard error."""
    returncode: int
    stdout: str
    stderr: str


class CommandServer:
    """A server process forking ``swerve`` commands (see the module doc); a context manager.

    Parameters
    ----------
    cwd : Path
        Working directory of the server and of every command.
    env : dict
        Environment of the server and of every command.
    scratch : Path
        Folder for the commands' standard output and error files.
    """

    def __init__(self, cwd: Path, env: dict[str, str], scratch: Path):
        self.scratch = scratch
        self.scratch.mkdir(parents=True, exist_ok=True)
        self._count = 0
        # -P: the tests' folder is not put on the server's import path
        self._proc = subprocess.Popen([sys.executable, "-P", __file__], cwd=cwd, env=env, stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
        #: What the server's imports printed (a fresh command would print it too): "" when clean.
        self.import_output: str = self._reply(timeout_s=300.0)["import_output"]

    def _reply(self, timeout_s: float) -> dict:
        ready, _, _ = select.select([self._proc.stdout], [], [], timeout_s)
        if not ready:
            raise TimeoutError(f"the command server did not answer within {timeout_s} s")
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the command server ended (status {self._proc.wait()})")
        return json.loads(line)

    def run(self, argv: list[str], timeout_s: float, cwd: Path | None = None,
            env: dict[str, str] | None = None) -> Finished:
        """Run ``swerve *argv`` in a forked child, in ``cwd`` (default: the server's) with ``env``
        set on the server's environment; kill it and raise :class:`TimeoutError` after
        ``timeout_s`` (a hang guard)."""
        self._count += 1
        prefix = self.scratch / f"cmd{self._count}"
        request = {"argv": argv, "out": str(prefix), "cwd": None if cwd is None else str(cwd), "env": env or {}}
        self._proc.stdin.write(json.dumps(request) + "\n")
        self._proc.stdin.flush()
        pid = self._reply(timeout_s=60.0)["pid"]
        try:
            status = self._reply(timeout_s)["status"]
        except TimeoutError:
            os.kill(pid, 9)
            self._reply(timeout_s=60.0)
            raise TimeoutError(f"swerve {' '.join(argv)} did not end within {timeout_s} s") from None
        return Finished(status, Path(f"{prefix}.out").read_text(errors="replace"),
                        Path(f"{prefix}.err").read_text(errors="replace"))

    def close(self) -> None:
        self._proc.stdin.close()
        self._proc.wait(timeout=60)
        self._proc.stdout.close()

    def __enter__(self) -> CommandServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _exit_status(code) -> int:
    """The status the interpreter exits with for ``SystemExit(code)`` (printing a non-int code)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF
    print(code, file=sys.stderr)
    return 1


def _child(cli, request: dict) -> None:
    """In the forked child: the working directory, environment and standard streams of
    ``request``, its ``swerve *argv`` run by ``cli`` (:mod:`swerve.tools.cli`), then exit."""
    argv, prefix = request["argv"], request["out"]
    if request["cwd"] is not None:
        os.chdir(request["cwd"])
    os.environ.update(request["env"])
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    for fd, suffix in ((1, ".out"), (2, ".err")):
        os.dup2(os.open(prefix + suffix, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
    sys.argv = [cli.__file__, *argv]
    try:
        status = _exit_status(cli.entry())
    except SystemExit as exc:
        status = _exit_status(exc.code)
    except BaseException:  # noqa: BLE001 - as the interpreter: the traceback on stderr, status 1
        traceback.print_exc()
        status = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(status)


def _serve() -> None:
    """The server: import every command, report what that printed, then fork one child a request."""
    proto_in = os.fdopen(os.dup(0), "r")
    proto_out = os.fdopen(os.dup(1), "w", buffering=1)
    capture = Path(os.environ.get("TMPDIR", "/tmp")) / f"swerve-command-server-{os.getpid()}.txt"
    with capture.open("w+") as noise:
        os.dup2(noise.fileno(), 1)
        os.dup2(noise.fileno(), 2)
        from swerve.tools import cli          # here, so that what importing it prints is captured

        for name in cli.COMMANDS:
            cli.command_module(name)
            cli.work_module(name)
        sys.stdout.flush()
        sys.stderr.flush()
        noise.seek(0)
        printed = noise.read()
    capture.unlink()
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)
    proto_out.write(json.dumps({"import_output": printed}) + "\n")
    for line in proto_in:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            proto_in.close()
            proto_out.close()
            _child(cli, request)
        proto_out.write(json.dumps({"pid": pid}) + "\n")
        _, wait_status = os.waitpid(pid, 0)
        proto_out.write(json.dumps({"status": os.waitstatus_to_exitcode(wait_status)}) + "\n")


if __name__ == "__main__":
    _serve()
