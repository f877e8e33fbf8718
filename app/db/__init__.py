"""Database: models, sessions and migrations (the local cluster the CLI runs: ``cli.ops``)."""
