"""Status rows for long batch jobs (``ingest_jobs``), readable over HTTP while a job runs."""
