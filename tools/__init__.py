"""Offline tools and the ``capstan`` command line: simulate, replay, export,
identify, close the model loop, experiments and benchmarks."""
