"""Raster layers over HTTP: XYZ tiles composed from COG sources, layer catalogue, TileJSON."""
