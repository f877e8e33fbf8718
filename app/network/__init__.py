"""The road network as a service: OGC API Features, vector tiles, authenticated editing."""
