"""``python -m shsas_core.cli`` = ``shsas``."""

import sys

from . import main

sys.exit(main())
