"""``python -m cli ...`` runs the ``ugvmap`` command (what tests and benchmarks spawn)."""

from cli.main import main

main()
