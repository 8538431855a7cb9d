"""``python -m bench``: run the benchmark suite (see :mod:`bench.suite`)."""

from .suite import main

raise SystemExit(main())
