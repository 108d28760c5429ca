"""Safe output files: the one atomic writer every file of the project goes through.

``atomic_path(path, overwrite=...)`` is a context manager that yields a temporary path in
the destination's own folder (``.<name>.<random>.tmp<suffix>``, the suffix kept so that
writers choosing a format by extension still do); when the block ends normally the file
is flushed to disk (``fsync``) and renamed over ``path`` (``os.replace``, atomic on one
file system), then the folder entry is synced. When the block raises (a write error, a
full disk, ``KeyboardInterrupt``) the temporary file is removed and ``path`` is left as it
was: a reader sees the old file or the whole new one, never a partial one.

``check_output_file`` / ``check_output_dir`` run the same checks *before* any work (the
CLI calls them before rendering): the folder exists or can be made, is a folder, is
writable (probed by creating and removing a file, so it also holds for root and for
read-only mounts), and the file is not there yet unless ``overwrite``. Every failure is an
``OutputError`` (an ``OSError``) whose message is one line naming the path; an existing
file is the ``OutputExistsError`` subclass (also a ``FileExistsError``).

Temporary files alive right now are listed in ``LIVE_TEMPORARIES`` so that a process that
must exit at once (the CLI on Ctrl-C, ``whitted.cli``) can remove them first
(``remove_live_temporaries``).
"""
from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import threading
from pathlib import Path

#: Temporary files being written now (removed on a clean exit of their block).
LIVE_TEMPORARIES: set[Path] = set()
_LOCK = threading.Lock()


class OutputError(OSError):
    """An output file or folder that cannot be written; the message is one line."""

    def __str__(self) -> str:
        return self.args[0] if self.args else "output error"


class OutputExistsError(OutputError, FileExistsError):
    """The output file exists and replacing it was not asked for."""


def _reason(e: OSError) -> str:
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return "no space left on the device"
    if e.errno == errno.EFBIG:
        return "file too large for the device or the process's file size limit"
    if e.errno in (errno.EACCES, errno.EPERM):
        return "permission denied"
    if e.errno == errno.EROFS:
        return "read-only file system"
    return e.strerror or str(e)


def check_output_dir(folder) -> Path:
    """Make ``folder`` (and its parents) if missing and prove it writable by creating and
    removing a probe file. Returns it as a Path; raises ``OutputError`` (one line) when a
    file stands where a folder is expected, or the folder cannot be made or written."""
    folder = Path(folder)
    for p in (folder, *folder.parents):
        if p.exists():
            if not p.is_dir():
                raise OutputError(f"{folder}: cannot write here: {p} is a file, not a folder")
            break
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".whitted-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise OutputError(f"{folder}: cannot write here: {_reason(e)}") from None
    return folder


def check_output_file(path, *, overwrite: bool = False, flag: str = "--overwrite") -> Path:
    """Check that ``path`` can be written: its folder as in ``check_output_dir``, not a
    folder itself, and not existing unless ``overwrite`` (``OutputExistsError`` naming
    ``flag``, the option that allows replacing it)."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; expected a file path")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path}: is not a regular file (a device, pipe or socket); "
                          "it is never replaced")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path}: exists (pass {flag} to replace it)")
    check_output_dir(path.parent)
    return path


def check_replaceable(path, *, ours, force: bool = False, what: str = "file",
                      flag: str = "--force") -> Path:
    """Check that ``path`` can be written, for an output that is rewritten on every run (a
    report): a missing path as in ``check_output_file``; an existing regular file only when
    ``ours(path)`` recognises it as one this tool wrote (a ``what``), or with ``force``;
    a device, pipe or socket never. Raises ``OutputExistsError`` / ``OutputError``."""
    path = Path(path)
    if path.exists() and path.is_file() and not force and not _is_ours(ours, path):
        raise OutputExistsError(f"{path}: exists and is not a {what} written by whitted "
                                f"(pass {flag} to replace it)")
    return check_output_file(path, overwrite=True, flag=flag)


def _is_ours(ours, path: Path) -> bool:
    try:
        return bool(ours(path))
    except (OSError, ValueError):
        return False


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path, *, overwrite: bool = False, flag: str = "--overwrite"):
    """Yield a temporary path beside ``path`` to write the whole file to; on a normal exit
    it is fsynced and renamed to ``path``; on an exception it is removed. Raises
    ``OutputExistsError`` if ``path`` exists and not ``overwrite`` (checked before and again
    just before the rename), ``OutputError`` for a folder that cannot be written or a
    write that failed (full disk, I/O error), with one line naming ``path``."""
    path = check_output_file(path, overwrite=overwrite, flag=flag)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}",
                               dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    os.chmod(tmp, 0o666 & ~_umask())     # mkstemp's 0600 would outlive the rename
    with _LOCK:
        LIVE_TEMPORARIES.add(tmp)
    try:
        try:
            yield tmp
            with open(tmp, "rb+") as f:
                os.fsync(f.fileno())
            if path.exists() and not overwrite:
                raise OutputExistsError(f"{path}: exists (pass {flag} to replace it)")
            os.replace(tmp, path)
        except OutputError:
            raise
        except OSError as e:
            raise OutputError(f"{path}: write failed: {_reason(e)}") from None
        except Exception as e:
            # a writer library's own exception type (OpenEXR, imageio) for a failed write
            cause = e.__cause__ or e.__context__
            if isinstance(cause, OSError) or "write" in str(e).lower():
                reason = _reason(cause) if isinstance(cause, OSError) else str(e)
                reason = " ".join(reason.replace(str(tmp), str(path)).split())
                raise OutputError(f"{path}: write failed: {reason}") from None
            raise
    finally:
        with _LOCK:
            LIVE_TEMPORARIES.discard(tmp)
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    _fsync_dir(path.parent)


def write_bytes(path, data: bytes, *, overwrite: bool = False,
                flag: str = "--overwrite") -> Path:
    """Write ``data`` to ``path`` atomically (see ``atomic_path``). Returns ``path``."""
    with atomic_path(path, overwrite=overwrite, flag=flag) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
    return Path(path)


def write_text(path, text: str, *, overwrite: bool = False, flag: str = "--overwrite",
               encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see ``atomic_path``). Returns ``path``."""
    return write_bytes(path, text.encode(encoding), overwrite=overwrite, flag=flag)


def remove_live_temporaries() -> None:
    """Remove every temporary file an ``atomic_path`` block is writing now (for a process
    about to exit without unwinding, e.g. on Ctrl-C)."""
    with _LOCK:
        for tmp in list(LIVE_TEMPORARIES):
            with contextlib.suppress(OSError):
                tmp.unlink()
        LIVE_TEMPORARIES.clear()
