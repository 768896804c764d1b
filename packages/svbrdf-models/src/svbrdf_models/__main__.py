"""``python -m svbrdf_models``: the ``svbrdf-models`` command."""

import sys

from .cli import main

sys.exit(main())
