"""Scaffolding shared by ``tests/`` and ``bench/``: throwaway databases, synthetic networks,
rasters and a country-sized OSM file with known answers, a real server process, the road
accuracy protocol.

Why a package of its own: these generators used to live in the product's packages (``app``,
``ingest``) although only tests and benchmarks ran them, and the benchmarks imported
``tests.conftest``. Nothing in ``app``, ``ingest`` or ``cli`` imports it, and it is not
installed with them. Generators a user runs stay in the product behind a command (the demo's
synthetic town in ``ugvmap demo``, the sample drive ``python -m ingest.ipm.synthetic``).
"""
