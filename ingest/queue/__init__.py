"""Queued jobs: the tasks ``ugvmap worker`` runs (:mod:`ingest.queue.tasks`), one module per
job kind that needs more than one task (:mod:`ingest.queue.raster`), the single-task runners
(:mod:`ingest.queue.runners`) and the worker loop (:mod:`ingest.queue.worker`).

What a job kind is, and how its parameters are checked, is :data:`app.jobs.kinds.JOB_KINDS`;
how a job is queued is :mod:`app.jobs.queue`.
"""
