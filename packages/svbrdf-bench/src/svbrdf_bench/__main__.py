"""``python -m svbrdf_bench``: the ``svbrdf-bench`` command."""

import sys

from .cli import main

sys.exit(main())
