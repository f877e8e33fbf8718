"""Database: models, sessions, the embedded local PostGIS cluster and migrations."""
