"""``python -m mmdopt.bench``: the ``mmdopt`` command line."""

import sys

from .cli import main

sys.exit(main())
