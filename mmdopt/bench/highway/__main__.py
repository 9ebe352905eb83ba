"""``python -m mmdopt.bench.highway [OPTIONS]``."""

from .cli import main

raise SystemExit(main())
