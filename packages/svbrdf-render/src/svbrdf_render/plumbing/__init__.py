"""Plumbing: what every command line of the four packages needs and none of them is about.

- :mod:`~svbrdf_render.plumbing.atomic`: files written whole or not at all, a whole folder
  swapped in one step, the leftovers of killed writers, an output folder checked before work;
- :mod:`~svbrdf_render.plumbing.processes`: beside other processes: the one lock between them,
  SIGTERM taken as Ctrl-C, and the interrupt exit status;
- :mod:`~svbrdf_render.plumbing.machine`: the device, the torch threads and the memory free;
- :mod:`~svbrdf_render.plumbing.progress`: the status line and the refinement's progress bar;
- :mod:`~svbrdf_render.plumbing.arguments`: the argparse kit and the exit statuses in words;
- :mod:`~svbrdf_render.plumbing.moved`: the finder that keeps a moved module's old name working
  for a release (each package's ``__init__`` installs it with its table; its ``install`` and
  ``spec_for`` are named from there).

Nothing here knows of maps, scenes or networks: it imports only :mod:`svbrdf_render.errors`,
whose errors it raises. The names below are the public ones; import them from here.
"""

from .arguments import EXIT_STATUS, Once, OneLineParser, float_range, int_range, positive_number
from .atomic import (
    atomic_output,
    check_output_folder,
    is_write_failure,
    remove_stale_temporaries,
    replace_folder,
    temporary_path,
    write_failure,
    write_text,
)
from .machine import (
    MAX_THREADS,
    THREADS_HELP,
    ThreadChoice,
    available_memory,
    choose_threads,
    pick_device,
    usable_cores,
)
from .processes import INTERRUPTED, LockHeld, locked, raise_if_interrupted, sigterm_as_interrupt
from .progress import ProgressBar, StatusLine

__all__ = [
    "EXIT_STATUS",
    "INTERRUPTED",
    "LockHeld",
    "MAX_THREADS",
    "Once",
    "OneLineParser",
    "ProgressBar",
    "StatusLine",
    "THREADS_HELP",
    "ThreadChoice",
    "atomic_output",
    "available_memory",
    "check_output_folder",
    "choose_threads",
    "float_range",
    "int_range",
    "is_write_failure",
    "locked",
    "pick_device",
    "positive_number",
    "raise_if_interrupted",
    "remove_stale_temporaries",
    "replace_folder",
    "sigterm_as_interrupt",
    "temporary_path",
    "usable_cores",
    "write_failure",
    "write_text",
]
