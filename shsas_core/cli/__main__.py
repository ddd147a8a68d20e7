"""``python -m shsas_core.cli``: the same entry point as the ``shsas`` script."""

import sys

from shsas_core.cli import main

sys.exit(main())
