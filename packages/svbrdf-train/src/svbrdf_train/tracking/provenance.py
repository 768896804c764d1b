"""Where a run comes from: code revision, versions, machine, command, as MLflow tags and as
what a checkpoint records (:func:`made_with`)."""

from __future__ import annotations

import contextlib
import importlib.metadata
import os
import platform
import subprocess
from pathlib import Path

import torch

__all__ = ["PACKAGES", "git_revision", "hardware", "made_with", "source_tags", "run_tags"]

#: The distributions whose versions every run records.
PACKAGES = ("svbrdf-render", "svbrdf-models", "svbrdf-train", "torch", "numpy", "mlflow")


def git_revision(folder: str | Path | None = None) -> tuple[str, bool]:
    """``(sha, dirty)`` of the git checkout holding ``folder`` (this package by default);
    ``("unknown", False)`` for an installed wheel or without git."""
    folder = Path(folder or Path(__file__).parent)
    try:
        sha = subprocess.run(
            ["git", "-C", str(folder), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if sha.returncode != 0:
            return "unknown", False
        status = subprocess.run(
            ["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        return sha.stdout.strip(), bool(status.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "unknown", False


def hardware(device: str | torch.device) -> str:
    """The machine a fit ran on, in words: the GPU's name, or the CPU's model and core count."""
    device = torch.device(device)
    if device.type == "cuda":
        return f"{torch.cuda.device_count()} x {torch.cuda.get_device_name(device)}"
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    threads = torch.get_num_threads()
    return f"{os.cpu_count()} cores of {name}, torch on {threads} thread{'s' if threads > 1 else ''}"


def made_with(device: str | torch.device) -> dict[str, str]:
    """What a checkpoint records about how it was made: code revision, versions, machine."""
    sha, dirty = git_revision()
    return {
        "git_sha": sha,
        "git_dirty": str(dirty).lower(),
        "torch": str(torch.__version__),
        "svbrdf_train": importlib.metadata.version("svbrdf-train"),
        "device": str(device),
        "hardware": hardware(device),
    }


def source_tags(command: str, sha: str | None = None) -> dict[str, str]:
    """MLflow's tags for where a run comes from, which its UI shows as the run's Source and
    "Created by": the command (``svbrdf-train fit``), of type LOCAL, at git commit ``sha`` (this
    checkout's by default; none for an installed wheel), and the user."""
    import getpass

    if sha is None:
        sha, _ = git_revision()
    tags = {"mlflow.source.name": command, "mlflow.source.type": "LOCAL"}
    if sha != "unknown":
        tags["mlflow.source.git.commit"] = sha
    with contextlib.suppress(Exception):  # no user name in some containers
        tags["mlflow.user"] = getpass.getuser()
    return tags


def run_tags(*, recipe: str, size: str, seed: int, device: str, world_size: int) -> dict[str, str]:
    """What identifies how a run was made: code, versions, machine, seed, recipe."""
    sha, dirty = git_revision()
    tags = {
        "recipe": recipe,
        "recipe.size": size,
        "seed": str(seed),
        "device": device,
        "world_size": str(world_size),
        "git_sha": sha,
        "git_dirty": str(dirty).lower(),
        **source_tags("svbrdf-train fit", sha),
        "mlflow.source.git.commit": sha,
        "host": platform.node(),
        "python": platform.python_version(),
    }
    for dist in PACKAGES:
        try:
            tags[f"version.{dist}"] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            tags[f"version.{dist}"] = "not installed"
    return tags
