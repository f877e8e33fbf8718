"""The ``ugvmap`` command line: the top layer, over the web app (``app``) and the batch jobs
(``ingest``). One module per capability registers its commands in :mod:`cli.main`; nothing
below this package imports it, so ``app`` never depends on ``ingest``."""
