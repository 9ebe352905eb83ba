"""``python -m mmdopt …`` = the ``mmdopt`` console script."""

import sys

from .cli import main

sys.exit(main())
