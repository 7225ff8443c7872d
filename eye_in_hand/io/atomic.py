"""Outputs that appear whole or not at all, and never silently replace earlier results.

Every command that writes a folder (``calibrate camera|stereo|handeye``, ``process``,
``simulate``) and the ``hand_eye`` node's ``hand_eye/save`` service build it with
:func:`atomic_output_dir`::

    with atomic_output_dir(out, overwrite=args.overwrite) as tmp:
        write_everything_into(tmp)          # tmp = <parent>/.<name>.partial-<pid>/<name>

The folder is built under a temporary name in the same parent folder (so that it carries its
final name inside: a rosbag2 bag names its storage file after its folder), every file is
flushed to disk (``fsync``), and it is then renamed into place:

- a new OUT appears in one ``rename``;
- an existing OUT is refused (:class:`OutputExistsError`, one line naming it and
  ``--overwrite``) unless ``overwrite`` is true, and then swapped with the new folder in one
  ``renameat2(RENAME_EXCHANGE)`` (Linux; elsewhere two renames through ``.<name>.old-<pid>``)
  and the old one deleted: never a mix of old and new files;
- an empty existing folder counts as absent.

A failure, Ctrl-C or ``kill -9`` at any moment leaves the old OUT (or nothing) at OUT, never a
half-written one. Leftovers of a killed run are recognisable (``.<name>.partial-<pid>``) and
are removed by the next run for the same OUT once their process is gone. ``OSError`` while
writing (a full disk, ``ENOSPC``; no permission) becomes :class:`OutputWriteError`: one line
naming the file and saying that OUT was left as it was.

Single files are written the same way by :func:`atomic_write_text` /
:func:`atomic_write_bytes` / :func:`atomic_file` (temporary file, ``fsync``, ``os.replace``).
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from eye_in_hand.errors import EyeInHandError

__all__ = [
    "OutputError",
    "OutputExistsError",
    "OutputWriteError",
    "PARTIAL_TAG",
    "check_output_dir",
    "atomic_output_dir",
    "atomic_file",
    "atomic_write_text",
    "atomic_write_bytes",
    "remove_stale_partials",
]

#: Marker in the names of temporary folders and files: ``.<name>.partial-<pid>``.
PARTIAL_TAG = ".partial-"
_OLD_TAG = ".old-"
_RENAME_EXCHANGE = 2  # linux/fs.h


class OutputError(EyeInHandError):
    """An output cannot be written (it is not a folder, its parent cannot be made, ...)."""


class OutputExistsError(OutputError):
    """The output exists already and ``--overwrite`` was not given."""


class OutputWriteError(OutputError):
    """Writing an output failed (full disk, permissions); the earlier output is unchanged.

    Attributes:
        filename: the file that could not be written (None when unknown).
        strerror: the system's reason (e.g. ``No space left on device``).
    """

    def __init__(self, message: str, filename: str | None = None,
                 strerror: str | None = None) -> None:
        super().__init__(message)
        self.filename = filename
        self.strerror = strerror


def _show(path: str | os.PathLike[str]) -> str:
    """``path`` printable on any terminal (non-UTF-8 bytes of a file name as ``\\xNN``)."""
    text = os.fspath(path)
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _is_nonempty_dir(path: Path) -> bool:
    try:
        with os.scandir(path) as it:
            return next(it, None) is not None
    except OSError:
        return False


def check_output_dir(out: str | os.PathLike[str], *, overwrite: bool = False,
                     option: str = "-o", hint: str = "give --overwrite to replace it",
                     inputs: Iterable[str | os.PathLike[str] | None] = ()) -> Path:
    """Check early (before any long work) that ``out`` may be written.

    Args:
        out: the output folder.
        overwrite: an existing folder may be replaced.
        option: the command-line option that named ``out``, for messages.
        hint: how to allow replacing it, for messages.
        inputs: the command's input files and folders (None entries are ignored): an ``out``
            that is one of them or holds one is refused even with ``overwrite`` (replacing it
            would delete the input).

    Returns:
        ``out`` as a Path.

    Raises:
        OutputError: ``out`` exists and is not a folder, or it is or holds an input.
        OutputExistsError: ``out`` is a non-empty folder and ``overwrite`` is false.
    """
    out = Path(out)
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise OutputError(f"{option} {_show(out)}: exists and is not a folder")
        real = out.resolve()
        for item in inputs:
            if item is None or os.fspath(item) == "":
                continue
            p = Path(item).resolve()
            if p == real or real in p.parents:
                raise OutputError(f"{option} {_show(out)}: holds the input {_show(item)}; "
                                  "choose another output")
        if not overwrite and _is_nonempty_dir(out):
            raise OutputExistsError(f"{option} {_show(out)}: exists already ({hint}, or "
                                    "choose another output)")
    return out


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: it exists, owned by someone else
        return True
    return True


def remove_stale_partials(out: str | os.PathLike[str]) -> list[Path]:
    """Remove ``.<name>.partial-<pid>`` leftovers of ``out`` whose process is gone.

    A ``.<name>.old-<pid>`` (the earlier output, left only when a two-rename replacement was
    killed between its renames) is moved back to ``out`` when ``out`` is missing, else removed.

    Returns:
        The leftovers removed or restored.
    """
    out = Path(out)
    parent = out.absolute().parent
    pattern = re.compile(re.escape("." + out.name) + r"\.(partial|old)-(\d+)(?:\.tmp)?$")
    done: list[Path] = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return done
    for entry in entries:
        m = pattern.match(entry.name)
        if not m or _pid_alive(int(m.group(2))):
            continue
        path = Path(entry.path)
        if m.group(1) == "old" and not (out.exists() or out.is_symlink()):
            with contextlib.suppress(OSError):
                os.rename(path, out)
                done.append(path)
            continue
        _remove(path)
        done.append(path)
    return done


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _fsync_path(path: Path, directory: bool) -> None:
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.EROFS, errno.EBADF):
            raise
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """Flush every file and folder under ``root`` to disk (so a rename publishes real data)."""
    for dirpath, _dirnames, filenames in os.walk(root):
        for name in filenames:
            p = Path(dirpath) / name
            if not p.is_symlink():
                _fsync_path(p, directory=False)
        _fsync_path(Path(dirpath), directory=True)


_LIBC: object = None


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False if unsupported."""
    global _LIBC
    if not hasattr(os, "sched_getaffinity"):  # not Linux
        return False
    # local: ctypes costs ~4 ms at every command's start-up, and only replacing an existing
    # output folder needs it
    import ctypes
    import ctypes.util

    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        except OSError:
            _LIBC = False
    fn = getattr(_LIBC, "renameat2", None) if _LIBC else None
    if fn is None:
        return False
    at_fdcwd = -100
    rc = fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), os.fspath(b))


def _commit(staged: Path, out: Path, overwrite: bool, option: str, hint: str) -> None:
    parent = out.absolute().parent
    if out.exists() or out.is_symlink():
        check_output_dir(out, overwrite=overwrite, option=option, hint=hint)  # it may be new
        if not _is_nonempty_dir(out):
            os.rmdir(out)
    if not (out.exists() or out.is_symlink()):
        os.rename(staged, out)
    elif _exchange(staged, out):
        _remove(staged)  # now the old folder
    else:
        old = parent / f".{out.name}{_OLD_TAG}{os.getpid()}"
        _remove(old)
        os.rename(out, old)
        os.rename(staged, out)
        _remove(old)
    _fsync_path(parent, directory=True)


def _newest_file(root: Path) -> str | None:
    newest: tuple[float, str] | None = None
    for dirpath, _dirnames, filenames in os.walk(root):
        for name in filenames:
            with contextlib.suppress(OSError):
                p = os.path.join(dirpath, name)
                key = (os.stat(p).st_mtime, p)
                newest = key if newest is None or key > newest else newest
    return None if newest is None else newest[1]


def _write_error(exc: OSError | OutputWriteError, out: Path, existed: bool,
                 staged: Path | None = None) -> OutputWriteError:
    """One line: the file (as it would be named in ``out``), the reason, and what was kept."""
    named = getattr(exc, "filename", None)
    filename = os.fspath(named) if named else None
    if filename is None and staged is not None:  # a write() failed: the file written last
        filename = _newest_file(staged)
    if filename is not None and staged is not None:
        with contextlib.suppress(ValueError):  # a file of the staged folder: its final name
            filename = os.fspath(out / Path(filename).absolute().relative_to(staged.absolute()))
    what = exc.strerror or str(exc)
    kept = (f"the earlier {_show(out)} is unchanged" if existed
            else f"nothing was written to {_show(out)}")
    where = _show(filename) if filename else _show(out)
    return OutputWriteError(f"{where}: cannot write ({what}); {kept}", filename, exc.strerror)


@contextlib.contextmanager
def atomic_output_dir(out: str | os.PathLike[str], *, overwrite: bool = False,
                      option: str = "-o", create: bool = True,
                      hint: str = "give --overwrite to replace it") -> Iterator[Path]:
    """Build the folder ``out`` under a temporary name and rename it into place on success.

    Args:
        out: the output folder.
        overwrite: replace an existing non-empty ``out`` (whole) instead of refusing it.
        option: the option that named ``out``, for messages (e.g. ``"-o"``, ``"--out"``).
        create: create the yielded folder; False for writers that create their folder
            themselves and refuse an existing one (a rosbag2 writer).
        hint: how to allow replacing ``out``, for messages.

    Yields:
        The folder to write into: ``<parent>/.<name>.partial-<pid>/<name>``.

    Raises:
        OutputError, OutputExistsError: as :func:`check_output_dir`.
        OutputWriteError: an ``OSError`` while writing or renaming (the exception inside the
            block is chained); ``out`` is unchanged.
        Any other exception from the block, after the temporary folder was removed.
    """
    out = check_output_dir(out, overwrite=overwrite, option=option, hint=hint)
    existed = _is_nonempty_dir(out)
    parent = out.absolute().parent
    root = parent / f".{out.name}{PARTIAL_TAG}{os.getpid()}"
    try:
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_partials(out)
        _remove(root)
        root.mkdir()
        staged = root / out.name
        if create:
            staged.mkdir()
    except OSError as exc:
        _remove(root)
        kept = f"the earlier {_show(out)} is unchanged" if existed else "nothing was written"
        raise OutputWriteError(f"{_show(parent)}: cannot create {_show(out.name)} there "
                               f"({exc.strerror or exc}); {kept}", os.fspath(parent),
                               exc.strerror) from exc
    try:
        yield staged
        if not staged.is_dir():
            raise OutputError(f"{_show(out)}: nothing was written")
        _fsync_tree(staged)
        _commit(staged, out, overwrite, option, hint)
    except (OSError, OutputWriteError) as exc:
        raise _write_error(exc, out, existed, staged) from exc
    except Exception as exc:
        # a writer that wrapped the system's error in its own (a bag writer's BagError, a
        # database's "disk is full"): still the file under its final name and what was kept
        cause = _write_cause(exc, staged)
        if cause is None:
            raise
        raise _write_error(cause, out, existed, staged) from exc
    finally:
        _remove(root)


#: sqlite3's words for a full disk or a file-size limit (it reports no errno)
_SQLITE_FULL = ("database or disk is full", "disk i/o error")


def _write_cause(exc: BaseException, staged: Path) -> OSError | None:
    """The ``OSError`` behind a writer's own exception, when it concerns the staged folder
    (its file is in it, or it names no file); a full sqlite3 database as ``ENOSPC``."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError):
            name = getattr(e, "filename", None)
            if name is None:
                return e
            with contextlib.suppress(ValueError):
                Path(os.fspath(name)).absolute().relative_to(staged.absolute())
                return e
            return None
        if type(e).__module__ == "sqlite3" and any(w in str(e).lower() for w in _SQLITE_FULL):
            return OSError(errno.ENOSPC, "database or disk is full")
        e = e.__cause__ or e.__context__
    return None


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike[str], mode: str = "w", *,
                encoding: str | None = "utf-8", newline: str | None = None) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; on success flush, ``fsync`` and rename it to
    ``path`` (replacing it). On any exception the temporary file is removed and ``path`` is
    unchanged.

    Args:
        path: the file to write.
        mode: ``"w"`` (text) or ``"wb"``.
        encoding, newline: as :func:`open` (text mode only).

    Raises:
        OutputWriteError: an ``OSError`` while writing (full disk, permissions).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    tmp = path.with_name(f".{path.name}{PARTIAL_TAG}{os.getpid()}.tmp")
    existed = path.exists()
    try:
        try:
            fh = (open(tmp, "wb") if mode == "wb"
                  else open(tmp, "w", encoding=encoding, newline=newline))
        except OSError as exc:
            raise _file_error(exc, path, existed) from exc
        try:
            with fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
            _fsync_path(path.absolute().parent, directory=True)
        except OSError as exc:
            raise _file_error(exc, path, existed) from exc
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _file_error(exc: OSError, path: Path, existed: bool) -> OutputWriteError:
    kept = "the earlier file is unchanged" if existed else "nothing was written"
    return OutputWriteError(f"{_show(path)}: cannot write ({exc.strerror or exc}); {kept}",
                            os.fspath(path), exc.strerror or str(exc))


def atomic_write_text(path: str | os.PathLike[str], text: str, *,
                      encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_file`)."""
    with atomic_file(path, "w", encoding=encoding) as fh:
        fh.write(text)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_file`)."""
    with atomic_file(path, "wb") as fh:
        fh.write(data)
