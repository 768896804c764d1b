"""``python -m svbrdf_train``: the ``svbrdf-train`` command (what torchrun starts)."""

import sys

from .cli import main

sys.exit(main())
