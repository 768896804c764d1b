"""How many torch threads a command takes: one per free core, unless told (issue 36: two
threads on a busy 2-core machine refined a photo 2-10x slower than one)."""

from __future__ import annotations

import pytest
import torch

from svbrdf_render.plumbing import machine


@pytest.fixture(autouse=True)
def _restore_threads(monkeypatch):
    before = torch.get_num_threads()
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(machine, "usable_cores", lambda: 4)
    yield
    torch.set_num_threads(before)


@pytest.mark.parametrize(
    ("load", "threads", "busy"), [(0.0, 4, False), (1.2, 3, True), (2.6, 1, True), (9.0, 1, True)]
)
def test_one_thread_per_free_core(monkeypatch, load, threads, busy):
    monkeypatch.setattr(machine, "_load", lambda: load)
    choice = machine.choose_threads()
    assert (choice.threads, choice.busy) == (threads, busy)
    assert torch.get_num_threads() == threads
    assert ("busy" in choice.describe()) == busy and f"{load:g} other tasks running" in choice.describe()


def test_what_the_user_asks_is_taken(monkeypatch):
    monkeypatch.setattr(machine, "_load", lambda: 9.0)
    assert machine.choose_threads(3).threads == 3 and not machine.choose_threads(3).busy
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    choice = machine.choose_threads()
    assert (choice.threads, choice.source) == (2, "OMP_NUM_THREADS")
    assert machine.choose_threads(1, apply=False).threads == 1 and torch.get_num_threads() == 2
    with pytest.raises(ValueError, match="from 1 to 4096"):
        machine.choose_threads(0)


def test_no_load_average_means_every_core(monkeypatch):
    monkeypatch.setattr(machine, "_load", lambda: None)
    assert machine.choose_threads().threads == 4


def test_the_tasks_running_now_count_not_the_lagging_load_average(monkeypatch, tmp_path):
    # /proc/loadavg's fourth field counts the tasks running now (this process among them); a
    # minute after a benchmark the load average still says 1.6 on an idle machine.
    loadavg = tmp_path / "loadavg"
    monkeypatch.setattr(machine, "_LOADAVG", str(loadavg))
    monkeypatch.setattr(machine.os, "getloadavg", lambda: (1.6, 1.0, 0.5))
    loadavg.write_text("1.60 1.00 0.50 1/310 4242\n")  # only this process runs
    assert machine.choose_threads().threads == 4
    loadavg.write_text("1.60 1.00 0.50 3/310 4242\n")  # two CPU-bound processes beside it
    choice = machine.choose_threads()
    assert (choice.threads, choice.busy) == (2, True) and "2 other tasks running" in choice.describe()
    loadavg.unlink()  # no such file (not Linux): the load average it is
    assert machine.choose_threads().threads == 2


def test_available_memory_is_the_kernels_lowered_to_the_cgroups_room(monkeypatch, tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       16000000 kB\nMemAvailable:    8000000 kB\n")
    monkeypatch.setattr(machine, "_MEMINFO", str(meminfo))
    monkeypatch.setattr(machine, "_CGROUP", tmp_path / "no-cgroup")
    assert machine.available_memory() == 8000000 * 1024
    cgroup = tmp_path / "cgroup"
    cgroup.mkdir()
    (cgroup / "memory.max").write_text("6000000000\n")
    (cgroup / "memory.current").write_text("2000000000\n")
    monkeypatch.setattr(machine, "_CGROUP", cgroup)
    assert machine.available_memory() == 4000000000  # the group's limit less what it uses
    (cgroup / "memory.max").write_text("max\n")  # no limit: the kernel's figure
    assert machine.available_memory() == 8000000 * 1024
    (cgroup / "memory.max").write_text("1000\n")
    (cgroup / "memory.current").write_text("5000\n")  # over its limit: nothing left, not negative
    assert machine.available_memory() == 0


def test_an_omp_num_threads_torch_cannot_take_is_ignored(monkeypatch):
    monkeypatch.setattr(machine, "_load", lambda: 0.0)
    monkeypatch.setattr(machine, "usable_cores", lambda: 2)
    monkeypatch.setenv("OMP_NUM_THREADS", str(2**40))  # torch.set_num_threads: "Overflow when unpacking long"
    choice = machine.choose_threads(apply=False)
    assert (choice.threads, choice.source) == (2, "free cores")
    monkeypatch.setenv("OMP_NUM_THREADS", str(machine.MAX_THREADS))
    assert machine.choose_threads(apply=False).threads == machine.MAX_THREADS
