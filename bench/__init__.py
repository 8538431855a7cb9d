"""pydynrad's benchmarks: ``python -m bench [--quick | --full]`` (see :mod:`bench.suite`)."""
