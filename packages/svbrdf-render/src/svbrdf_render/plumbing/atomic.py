"""Writing files so that a failure leaves nothing half-written and says so in one line.

Every file the four command lines write goes through :func:`atomic_output`: the writer fills
a temporary file beside the target (``.NAME.PID.tmp``, one per process so two writers never
share one), which is flushed to disk and renamed over the target only when it is whole. On
any failure (disk full, quota, file-size limit, read-only file system, permission, I/O error)
the temporary file is removed, the previous target is left as it was, and an
:class:`~svbrdf_render.errors.OutputError` says which file, why, and what to do; the command
lines print it as one line and exit with status 3
(:data:`~svbrdf_render.plumbing.arguments.EXIT_STATUS` words them all).

A process killed outright (SIGKILL, power loss) cannot remove its temporary file;
:func:`remove_stale_temporaries` removes those whose process is gone, and the trainer calls it
on its output folder when a fit starts or resumes. :func:`check_output_folder` proves before
any work that an output folder can be written, and :func:`replace_folder` swaps a whole folder
in one step.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path

from ..errors import OutputError, SVBRDFError

__all__ = [
    "atomic_output",
    "write_text",
    "write_failure",
    "is_write_failure",
    "temporary_path",
    "replace_folder",
    "remove_stale_temporaries",
    "check_output_folder",
]

# errno values that mean "the system refused to store the bytes", not "bad input".
_WRITE_ERRNOS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EIO: "input/output error",
}
_PATH_ERRNOS = {
    errno.ENOTDIR: "a file is in the way of its folder",
    errno.EEXIST: "a file is in the way of its folder",
    errno.EISDIR: "a folder is in its place",
    errno.ENOENT: "its folder cannot be made",
    errno.ENAMETOOLONG: "the name is too long",
}
_ERRNO_IN_TEXT = re.compile(r"errno\s*=?\s*(\d+)|\[Errno (\d+)\]")
# torch.save and h5py report a failed write as RuntimeError with one of these in the text
_IO_WORDS = re.compile(r"write|flush|no space|errno|i/o|iostream|unexpected pos|file", re.IGNORECASE)

_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.tmp$")


def temporary_path(path: str | os.PathLike) -> Path:
    """The temporary file :func:`atomic_output` fills for ``path`` in this process."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def _chain(error: BaseException) -> list[BaseException]:
    """``error`` and the exceptions it was raised from or during (torch wraps an OSError)."""
    out: list[BaseException] = []
    while error is not None and error not in out:
        out.append(error)
        error = error.__cause__ or error.__context__
    return out


def is_write_failure(error: BaseException) -> bool:
    """Whether ``error`` is the system refusing a write (rather than a bug or bad input)."""
    return any(
        isinstance(e, OSError) or (isinstance(e, RuntimeError) and bool(_IO_WORDS.search(str(e))))
        for e in _chain(error)
    )


def _errno_of(error: BaseException) -> int | None:
    for e in _chain(error):
        code = getattr(e, "errno", None)
        if isinstance(code, int):
            return code
        found = _ERRNO_IN_TEXT.search(str(e))
        if found:
            return int(found.group(1) or found.group(2))
    return None


def _free_space(folder: Path) -> str:
    for candidate in (folder, *folder.parents):
        with contextlib.suppress(OSError):
            if candidate.exists():
                free = shutil.disk_usage(candidate).free
                if free < 2**30:
                    return f"{free / 2**20:.1f} MiB free there"
                return f"{free / 2**30:.1f} GiB free there"
    return "free space unknown"


def write_failure(path: str | os.PathLike, error: BaseException, what: str = "write") -> SVBRDFError:
    """One line for a failed write of ``path``: the reason in words, and what to do.

    An :class:`OutputError` (exit status 3) when the system refused the bytes; a plain
    :class:`SVBRDFError` (exit status 2) when the path itself cannot be a file (a file in the
    way of its folder, a folder in its place).
    """
    path = Path(path)
    code = _errno_of(error)
    if code in _PATH_ERRNOS:
        return SVBRDFError(f"{path}: cannot {what} it: {_PATH_ERRNOS[code]}; give another path")
    reason = _WRITE_ERRNOS.get(code) if code is not None else None
    if code in (errno.ENOSPC, errno.EDQUOT):
        hint = f"{_free_space(path.parent)}; free some space or write it elsewhere"
    elif code == errno.EFBIG:
        hint = "over a file-size limit (ulimit -f) or the file system's largest file; write it elsewhere"
    elif code in (errno.EROFS, errno.EACCES, errno.EPERM):
        hint = "choose a folder you can write to"
    else:
        text = str(error).strip().splitlines()[0][:160] if str(error).strip() else type(error).__name__
        reason = reason or (os.strerror(code) if code is not None else text)
        hint = f"{_free_space(path.parent)}; check the disk and that the folder is writable"
    return OutputError(f"{path}: cannot {what} it: {reason} ({hint}); nothing half-written was left")


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write ``path`` through; rename it over ``path`` when whole.

    The folder is made if needed. The temporary file is synced to disk before the rename, so
    a crash leaves the old file or the new one, never a mix. A write failure inside the block
    (an ``OSError``, or the ``RuntimeError`` torch and h5py raise for one) becomes an
    :class:`OutputError` naming ``path``; any other exception passes through. Either way the
    temporary file is gone and ``path`` is as it was.

    Example:
        >>> from PIL import Image
        >>> image = Image.new("RGB", (8, 8))
        >>> with atomic_output("out/grid.png") as tmp:
        ...     image.save(tmp, format="PNG")
        >>> sorted(p.name for p in Path("out").iterdir())   # the folder made, no temporary left
        ['grid.png']
    """
    path = Path(path)
    tmp = temporary_path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(e, SVBRDFError) or not is_write_failure(e):
            raise
        raise write_failure(path, e) from None
    _fsync_folder(path.parent)


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` in one step (Linux ``renameat2(RENAME_EXCHANGE)``); False where the
    system has no such call (then nothing moved)."""
    import ctypes

    try:
        call = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    call.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    here, exchange = -100, 2  # AT_FDCWD, RENAME_EXCHANGE
    if call(here, os.fsencode(a), here, os.fsencode(b), exchange) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):  # no such call, or not here
        return False
    raise OSError(code, os.strerror(code), str(b))


def replace_folder(stage: str | os.PathLike, folder: str | os.PathLike, keep=()) -> None:
    """Put the whole folder ``stage`` in the place of ``folder``, so that a reader (and a crash at
    any moment) sees the old folder or the new one, never a mix: a new ``folder`` is one rename;
    an existing one is swapped with ``stage`` in one step where the system can (Linux), after
    which ``stage`` holds the old folder for the caller to remove. Elsewhere the old folder is
    renamed aside first (a crash between the two renames leaves it there, whole, as
    ``.NAME.PID.old``). Entries of the old folder named in neither ``stage`` nor ``keep``'s
    complement are carried over (hard links, else copies): what a user put beside the files
    this writer owns stays; the names in ``keep`` (the writer's own files) are not carried over,
    so those an earlier run wrote and this one did not go."""
    stage, folder = Path(stage), Path(folder)
    if not folder.exists() and not folder.is_symlink():
        os.replace(stage, folder)
        return
    own = set(keep)
    for old in folder.iterdir():
        if old.name in own or (stage / old.name).exists():
            continue
        if old.is_dir() and not old.is_symlink():
            shutil.copytree(old, stage / old.name, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(old, stage / old.name)
    if _exchange(stage, folder):
        return
    aside = folder.with_name(f".{folder.name}.{os.getpid()}.old")
    os.replace(folder, aside)
    os.replace(stage, folder)
    os.replace(aside, stage)  # the caller removes its stage: now the old folder


def _link_or_copy(src, dst) -> None:
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:
        shutil.copy2(src, dst, follow_symlinks=False)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`atomic_output`."""
    path = Path(path)
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (where the platform lets a folder be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a folder; the rename still happened
        pass
    finally:
        os.close(fd)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike, names: tuple[str, ...] | None = None) -> list[Path]:
    """Remove the ``.NAME.PID.tmp`` files in ``folder`` whose process is no longer running.

    ``names`` limits it to temporaries of those targets (e.g. ``("last.pt", "last.json")``).
    Returns what was removed. Temporaries of running processes are left alone.
    """
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    for entry in folder.iterdir():
        match = _TEMPORARY.match(entry.name)
        if not match or (names is not None and match["name"] not in names):
            continue
        if _alive(int(match["pid"])) or not entry.is_file():
            continue
        with contextlib.suppress(FileNotFoundError):
            entry.unlink()
            removed.append(entry)
    return removed


def check_output_folder(folder: str | os.PathLike, flag: str) -> Path:
    """Prove that ``folder`` can be made (or written in) before any work starts; makes nothing.

    A probe entry is created and removed in ``folder``, or in its nearest existing parent when
    it does not exist yet (checking access bits is not enough: root ignores them). Raises
    :class:`SVBRDFError` (bad input: exit status 2) naming ``flag`` and the folder when it
    cannot: a file in the way, a read-only file system, no permission.
    """
    folder = Path(folder)
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        if not existing.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a folder", str(existing))
        probe = temporary_path(existing / ".write-check")
        probe.mkdir()
        probe.rmdir()
    except OSError as e:
        reason = _WRITE_ERRNOS.get(e.errno or -1) or e.strerror or str(e)
        if isinstance(e, (FileExistsError, NotADirectoryError)):
            reason = f"{existing} is a file, not a folder"
        raise SVBRDFError(
            f"{flag} {folder}: cannot write there: {reason}; choose a folder you can write to"
        ) from None
    return folder
