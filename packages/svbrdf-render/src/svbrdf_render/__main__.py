"""``python -m svbrdf_render``: the ``svbrdf-render`` command."""

import sys

from .cli import main

sys.exit(main())
