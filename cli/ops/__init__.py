"""What the command line does to a deployment, apart from its command definitions: backup and
restore, the nginx front cache of ``ugvmap serve --front-cache``, a network's integrity report
and its deletion.

The service never runs these, so they live with the command line rather than in ``app/``;
they are plain functions and classes (no click), which tests and benchmarks call directly.
"""
