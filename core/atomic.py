"""Write a file so that it is either the old one or the whole new one, never a partial one.

Every output swerve writes (gain schedules, CSV, plots, config edits, the emulator's status
file, summaries) goes through :func:`atomic_write`: the bytes go to a temporary file created by
:func:`tempfile.mkstemp` in the target's own folder (an unpredictable name, opened with
``O_EXCL``, so the temporary itself is never a symlink), are flushed to disk, and the file is
renamed over the target with :func:`os.replace` (atomic on POSIX within one file system). A
crash, a full disk or an exception inside the ``with`` block leaves the old file untouched and
removes the temporary; the error names the file and the reason (``No space left on device``).

A path that is a symlink is written through: the file the link names is replaced (in its own
folder, keeping its permission bits) and the link stays a link, as ``open(path, "w")`` would.
A file with no write permission is refused, never replaced. :func:`check_writable` makes the
same checks (and creates and removes a probe file beside the target) without writing, so a
command can refuse a read-only target before it does any work.

It lives below every layer so that the controller, the emulator and the tools can all use it.
"""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from swerve.core.errors import SwerveError


class OutputError(SwerveError, OSError):
    """An output file could not be written; the message names the file and the OS reason."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _umask_mode() -> int:
    """Permission bits a plain ``open(path, "w")`` would give a new file (0o666 minus the umask)."""
    return 0o666 & ~_umask()


#: Free space :func:`check_writable` asks for beyond the size of the file it will replace, bytes.
SPACE_MARGIN_BYTES = 64 * 1024


def resolve_target(path: str | os.PathLike) -> Path:
    """The file a write to ``path`` replaces: ``path`` itself, or the file its symlinks name.

    Raises :class:`OutputError` for a symlink loop.
    """
    target = Path(path)
    if not target.is_symlink():
        return target
    real = Path(os.path.realpath(target))
    if real.is_symlink():
        raise OutputError(f"cannot write {target}: symlink loop")
    return real


def _refuse_read_only(target: Path, shown: Path) -> None:
    """Raise :class:`OutputError` when ``target`` exists without write permission."""
    try:
        st = target.stat()
    except OSError:         # absent (or unreachable: the write itself then says why)
        return
    if stat.S_ISDIR(st.st_mode):
        raise OutputError(f"cannot write {shown}: Is a directory")
    via = "" if target == shown else f" (the link's target {target})"
    if not st.st_mode & 0o222:
        raise OutputError(f"cannot write {shown}{via}: the file is read-only "
                          f"(mode {stat.S_IMODE(st.st_mode):04o})")
    if not os.access(target, os.W_OK):
        code = errno.EROFS if os.statvfs(target).f_flag & os.ST_RDONLY else errno.EACCES
        raise OutputError(f"cannot write {shown}{via}: {os.strerror(code)}")


def check_writable(path: str | os.PathLike, *, mkdir: bool = True) -> Path:
    """Check, without changing anything, that :func:`atomic_write` could replace ``path`` now.

    Follows symlinks, refuses a read-only file, creates and removes a probe file in the target's
    folder (or its nearest existing ancestor when ``mkdir``), which catches a read-only folder or
    mount, and asks for the file's present size plus :data:`SPACE_MARGIN_BYTES` of free space.
    Returns the file that would be replaced; raises :class:`OutputError`.
    """
    shown = Path(path)
    target = resolve_target(shown)
    _refuse_read_only(target, shown)
    folder = target.parent
    while mkdir and not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        if not folder.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, f"{folder} is not a directory")
        fd, probe = tempfile.mkstemp(dir=folder, prefix=f".{target.name}.", suffix=".probe")
        os.close(fd)
        os.unlink(probe)
        fs = os.statvfs(folder)
        try:
            size = target.stat().st_size
        except OSError:
            size = 0
        if fs.f_bavail * fs.f_frsize < size + SPACE_MARGIN_BYTES:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    except OSError as exc:
        raise OutputError(f"cannot write {shown}: {exc.strerror or exc}") from None
    return target


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", *, encoding: str | None = None,
                 newline: str | None = None, fsync: bool = True, mkdir: bool = True) -> Iterator[IO]:
    """Open a temporary file beside ``path`` for writing; on a clean exit rename it onto ``path``.

    ``mode``: ``"w"`` (text, UTF-8 unless ``encoding``) or ``"wb"``. ``fsync``: flush the data
    to disk before the rename (off for files rewritten many times a second). ``mkdir``: create
    missing parent folders. The new file keeps the permission bits of the file it replaces
    (a new file gets the umask's); a symlink is written through (see the module notes), and a
    read-only file is refused. Raises :class:`OutputError` (one line: file and reason) when
    the folder or the file cannot be written; any exception leaves ``path`` as it was.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', got {mode!r}")
    shown = Path(path)
    target = resolve_target(shown)
    _refuse_read_only(target, shown)
    try:
        if mkdir:
            for folder in (target.parent, *target.parent.parents):
                if folder.exists() and not folder.is_dir():
                    raise NotADirectoryError(20, f"{folder} is not a directory")
            target.parent.mkdir(parents=True, exist_ok=True)
        if target.is_dir():
            raise IsADirectoryError(21, "Is a directory")
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as exc:
        raise OutputError(f"cannot write {shown}: {exc.strerror or exc}") from None
    try:
        kw = {} if mode == "wb" else {"encoding": encoding or "utf-8", "newline": newline}
        with os.fdopen(fd, mode, **kw) as fh:
            yield fh
            fh.flush()
            if fsync:
                os.fsync(fh.fileno())
        try:
            perms = target.stat().st_mode & 0o7777
        except FileNotFoundError:
            perms = _umask_mode()
        os.chmod(tmp, perms)
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"cannot write {shown}: {exc.strerror or exc}") from None
        raise


@contextlib.contextmanager
def files_into(folder: str | os.PathLike) -> Iterator[Path]:
    """A temporary folder whose files join ``folder`` only when the ``with`` block succeeds.

    The temporary folder is made beside ``folder`` (same file system); on a clean exit its files
    are renamed into ``folder`` (created by renaming the temporary folder itself when absent),
    replacing files of the same names. On any exception (a full disk while writing, ...) the
    temporary folder is removed and ``folder`` is as it was: no partial folder is left, and an
    :class:`OutputError` names the file under ``folder``, not the temporary one.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"cannot write into {folder}: not a directory")
    base = folder.parent
    while not base.exists() and base != base.parent:
        base = base.parent
    try:
        tmp = Path(tempfile.mkdtemp(dir=base, prefix=f".{folder.name}."))
    except OSError as exc:
        raise OutputError(f"cannot write into {folder}: {exc.strerror or exc}") from None
    try:
        try:
            yield tmp
        except OutputError as exc:
            raise OutputError(str(exc).replace(str(tmp), str(folder))) from None
        folder.parent.mkdir(parents=True, exist_ok=True)
        if not folder.exists():
            os.chmod(tmp, 0o777 & ~_umask())
            os.rename(tmp, folder)
            return
        for item in sorted(tmp.iterdir()):
            if item.is_dir():
                raise OutputError(f"cannot write into {folder}: {item.name} is a folder")
            os.replace(item, folder / item.name)
        os.rmdir(tmp)
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"cannot write into {folder}: {exc.strerror or exc}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_text(path: str | os.PathLike, text: str, **kw) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write`); returns the path."""
    with atomic_write(path, "w", **kw) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes, **kw) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`); returns the path."""
    with atomic_write(path, "wb", **kw) as fh:
        fh.write(data)
    return Path(path)


def save_figure(fig, path: str | os.PathLike, **savefig_kw) -> Path:
    """``fig.savefig`` to ``path`` atomically, the format taken from the suffix (``.png``, ...)."""
    p = Path(path)
    with atomic_write(p, "wb") as fh:
        fig.savefig(fh, format=p.suffix.lstrip(".") or "png", **savefig_kw)
    return p


__all__ = ["OutputError", "atomic_write", "check_writable", "files_into", "resolve_target", "save_figure", "write_bytes", "write_text"]
