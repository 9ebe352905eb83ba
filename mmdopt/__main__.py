"""``python -m mmdopt …`` = the ``mmdopt`` console script."""

import sys

from .bench.cli import main

sys.exit(main())
