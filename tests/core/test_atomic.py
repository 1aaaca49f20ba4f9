"""Outputs are written to a private temporary file beside the target and renamed into place:
a failure mid-write (a full disk) leaves the old file or nothing, and one line of error."""
import errno
import os
import stat

import numpy as np
import pytest

from swerve.core import atomic
from swerve.core.atomic import OutputError, atomic_write, write_text
from swerve.tools.cli import main


def _disk_full_after(monkeypatch, n_bytes: int):
    """Make ``os.fdopen`` files of :mod:`swerve.core.atomic` fail with ENOSPC past ``n_bytes``."""
    real_fdopen = os.fdopen

    class Full:
        def __init__(self, fh):
            self._fh, self._n = fh, 0

        def write(self, data):
            self._n += len(data)
            if self._n > n_bytes:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return self._fh.write(data)

        def __getattr__(self, name):
            return getattr(self._fh, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self._fh.__exit__(*exc)

    monkeypatch.setattr(atomic.os, "fdopen", lambda *a, **k: Full(real_fdopen(*a, **k)))


def test_a_full_disk_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "out.txt"
    target.write_text("old\n")
    _disk_full_after(monkeypatch, 10)
    with pytest.raises(OutputError, match=r"cannot write .*out\.txt: No space left on device"):
        write_text(target, "new and much longer than ten bytes\n")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_an_exception_inside_the_block_leaves_nothing_new(tmp_path):
    target = tmp_path / "new.bin"
    with pytest.raises(RuntimeError):
        with atomic_write(target, "wb") as fh:
            fh.write(b"partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_the_temporary_is_private_and_a_symlink_is_written_through(tmp_path):
    real_dir = tmp_path / "real"
    real_dir.mkdir()
    victim = real_dir / "robot.yaml"
    victim.write_text("keep\n")
    victim.chmod(0o640)
    link = tmp_path / "out.txt"
    link.symlink_to(victim)
    with atomic_write(link) as fh:
        seen = [p for p in real_dir.iterdir() if p.name.startswith(".robot.yaml.")]
        modes = [stat.S_IMODE(os.lstat(p).st_mode) for p in seen]
        fh.write("new\n")
    assert len(seen) == 1 and modes == [0o600]
    assert link.is_symlink() and os.readlink(link) == str(victim)
    assert victim.read_text() == "new\n" and stat.S_IMODE(victim.stat().st_mode) == 0o640
    assert sorted(p.name for p in real_dir.iterdir()) == ["robot.yaml"]


def test_a_read_only_file_is_refused_not_replaced(tmp_path):
    target = tmp_path / "robot.yaml"
    target.write_text("a: 1\n")
    target.chmod(0o444)
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    for path in (target, link):
        with pytest.raises(OutputError, match=r"robot\.yaml.*: the file is read-only \(mode 0444\)"):
            write_text(path, "a: 2\n")
        with pytest.raises(OutputError, match="read-only"):
            atomic.check_writable(path)
    assert target.read_text() == "a: 1\n" and sorted(p.name for p in tmp_path.iterdir()) == ["link.yaml",
                                                                                             "robot.yaml"]


def test_a_symlink_loop_is_one_line(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(OutputError, match="symlink loop"):
        write_text(a, "x")


def test_a_replaced_file_keeps_its_permissions(tmp_path):
    target = tmp_path / "robot.yaml"
    target.write_text("a: 1\n")
    target.chmod(0o640)
    write_text(target, "a: 2\n")
    assert stat.S_IMODE(target.stat().st_mode) == 0o640 and target.read_text() == "a: 2\n"


def test_synth_on_a_full_disk_keeps_the_old_gains_and_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    out = tmp_path / "g.npz"
    assert main(["synth", "--trajectory", "line", "--out", str(out), "--quiet"]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    _disk_full_after(monkeypatch, 4096)
    assert main(["synth", "--trajectory", "line", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "g.npz" in err[0]
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.dat", "g.npz"]
    from swerve.controller.gains_io import load_gains
    assert np.isfinite(load_gains(out).K).all()
