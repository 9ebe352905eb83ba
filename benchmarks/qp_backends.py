"""QP backends on batches of projection QPs: a thin script.

The benchmark lives in the package, :mod:`mmdopt.bench.qp_backends`, so that
``mmdopt bench qp-backends`` works from an installed wheel; this script only calls it::

    python -m benchmarks.qp_backends                 # both families, 1000 QPs each
    python -m benchmarks.qp_backends --quick         # 100 QPs each
    python -m benchmarks.qp_backends --family two-axis --backends ipm,qpsolvers:piqp
"""

from __future__ import annotations

from mmdopt.bench.qp_backends import main

if __name__ == "__main__":
    raise SystemExit(main())
