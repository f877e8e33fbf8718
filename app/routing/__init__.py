"""Route planning over the live road network: in-memory graph, snapping, OSRM-shaped answers."""
