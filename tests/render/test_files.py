"""svbrdf_render.plumbing: atomic writes, one-line write failures, leftovers of killed writers, SIGTERM
as Ctrl-C and the lock."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys

import pytest

from svbrdf_render.errors import OutputError, SVBRDFError, exit_status
from svbrdf_render.plumbing import (
    LockHeld,
    atomic_output,
    check_output_folder,
    locked,
    remove_stale_temporaries,
    temporary_path,
    write_failure,
    write_text,
)


def test_a_whole_write_replaces_the_target_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "sub" / "a.txt"
    write_text(target, "one")
    write_text(target, "two")
    assert target.read_text() == "two"
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.txt"]


@pytest.mark.parametrize(
    "code, words, status",
    [
        (errno.ENOSPC, "no space left", 3),
        (errno.EFBIG, "file too large", 3),
        (errno.EROFS, "read-only", 3),
        (errno.EIO, "input/output", 3),
        (errno.ENOTDIR, "a file is in the way", 2),
    ],
)
def test_a_failed_write_keeps_the_old_file_and_says_why_in_one_line(tmp_path, code, words, status):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(SVBRDFError) as e:
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise OSError(code, "refused")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    message = str(e.value)
    assert message.startswith(str(target)) and words in message and "\n" not in message
    assert exit_status(e.value) == status


def test_a_wrapped_os_error_is_still_a_write_failure(tmp_path):
    """torch.save raises RuntimeError('unexpected pos ...') during an OSError(ENOSPC)."""
    try:
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598")  # noqa: B904
    except RuntimeError as e:
        error = write_failure(tmp_path / "last.pt", e)
    assert isinstance(error, OutputError) and "no space left" in str(error)


def test_other_exceptions_pass_through_and_still_clean_up(tmp_path):
    target = tmp_path / "a.txt"
    with pytest.raises(KeyError):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise KeyError("a bug, not the disk")
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_dead_processes_go_and_live_ones_stay(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)  # that process has exited
    stale = tmp_path / f".last.pt.{dead_pid}.tmp"
    live = temporary_path(tmp_path / "last.pt")  # this process: still writing
    other = tmp_path / f".notes.txt.{dead_pid}.tmp"
    for p in (stale, live, other):
        p.write_bytes(b"x")
    removed = remove_stale_temporaries(tmp_path, ("last.pt",))
    assert removed == [stale]
    assert live.exists() and other.exists()


def test_an_output_folder_is_checked_without_being_made(tmp_path):
    assert check_output_folder(tmp_path / "new" / "deeper", "-o") == tmp_path / "new" / "deeper"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(SVBRDFError, match=r"-o .*file/out: cannot write there: .* is a file") as e:
        check_output_folder(tmp_path / "file" / "out", "-o")
    assert exit_status(e.value) == 2


# -- locked: the one inter-process lock ------------------------------------------------------------


def _hold(path, ready, release, **options):
    """In a child process: hold ``locked(path, **options)`` until ``release`` is set."""
    with locked(path, **options):
        ready.set()
        release.wait(10)


def test_a_lock_not_waited_for_is_refused_naming_the_holders_pid(tmp_path):
    """``wait=False`` raises LockHeld at once; with ``pid=True`` the holder's PID is in the lock
    file for the refused process to read, and the file goes with the holder."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    path = tmp_path / "run" / ".fit.lock"
    ready, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold, args=(path, ready, release), kwargs={"pid": True})
    holder.start()
    try:
        assert ready.wait(10)
        assert path.read_text() == f"{holder.pid}\n"
        with pytest.raises(LockHeld) as refused, locked(path, wait=False, pid=True):
            pass
        assert refused.value.holder == str(holder.pid) and f"PID {holder.pid}" in str(refused.value)
        with pytest.raises(LockHeld) as refused, locked(path, wait=False):
            pass
        assert refused.value.holder is None  # without pid=True the file is not read
    finally:
        release.set()
        holder.join(10)
    assert not path.exists()  # removed by its holder
    with locked(path, wait=False, pid=True):
        assert path.read_text().strip() == str(os.getpid())


def test_a_process_waiting_on_a_lock_file_its_holder_removes_locks_the_new_one(tmp_path):
    """The waiter blocked on the file the holder removes on release must not hold the removed
    file (a third process would lock a new one beside it): it locks what is at the path now."""
    import multiprocessing
    import time

    ctx = multiprocessing.get_context("fork")
    path = tmp_path / "x.lock"
    ready, release = ctx.Event(), ctx.Event()
    first = ctx.Process(target=_hold, args=(path, ready, release), kwargs={"pid": True})
    first.start()
    assert ready.wait(10)
    ready2, release2 = ctx.Event(), ctx.Event()
    second = ctx.Process(target=_hold, args=(path, ready2, release2), kwargs={"pid": True})
    second.start()
    try:
        time.sleep(0.3)  # the second has opened the file and waits on it
        assert not ready2.is_set()
        release.set()
        first.join(10)
        assert ready2.wait(10)
        assert path.read_text() == f"{second.pid}\n"
        with pytest.raises(LockHeld):
            with locked(path, wait=False):
                pass
    finally:
        release.set()
        release2.set()
        first.join(10)
        second.join(10)


def test_a_pid_is_written_in_a_lock_file_not_a_folder(tmp_path):
    with pytest.raises(ValueError, match="not a folder"), locked(tmp_path, pid=True):
        pass
    with locked(tmp_path, wait=False):  # a folder is locked as it is: nothing written in it
        assert list(tmp_path.iterdir()) == []


# -- a stop asked by a signal is not lost ------------------------------------------------------


class _DropsItsException:
    """Sends SIGTERM to this process from ``__del__``: the handler runs there, and Python drops
    the KeyboardInterrupt it raises ("Exception ignored in ..."), as when the signal lands in a
    weakref callback of h5py or torch."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # the eval loop runs the pending handler here, inside __del__
            pass


def test_an_interrupt_python_drops_is_raised_again_at_the_next_check(capsys):
    from svbrdf_render.plumbing import raise_if_interrupted, sigterm_as_interrupt

    went_on = []
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
        with sigterm_as_interrupt():
            _DropsItsException()  # freed at once: the signal's exception is dropped
            went_on.append(True)  # the block goes on, as the command did
            raise_if_interrupted()
    assert went_on == [True]
    raise_if_interrupted()  # outside the block nothing is pending any more
    assert signal.getsignal(signal.SIGTERM) is before
    assert "Exception ignored" not in capsys.readouterr().err  # the dropped one is not an error
    hook = sys.unraisablehook
    with sigterm_as_interrupt():
        assert sys.unraisablehook is not hook
    assert sys.unraisablehook is hook


def test_ctrl_c_is_remembered_only_where_pythons_own_handler_is_in_place():
    from svbrdf_render.plumbing import raise_if_interrupted, sigterm_as_interrupt

    before = signal.getsignal(signal.SIGINT)
    with sigterm_as_interrupt():
        assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            raise_if_interrupted()  # remembered until the block ends
    raise_if_interrupted()
    assert signal.getsignal(signal.SIGINT) is before

    def own(signum, frame):  # a command's own handler (a fit's) is left alone
        pass

    signal.signal(signal.SIGINT, own)
    try:
        with sigterm_as_interrupt():
            assert signal.getsignal(signal.SIGINT) is own
        assert signal.getsignal(signal.SIGINT) is own
    finally:
        signal.signal(signal.SIGINT, before)
