"""The offline mission package: what a vehicle needs on board for an area when it has no link
to the server (tile archives of raster layers, the network as GeoPackage, Lanelet2 and vector
tiles, a manifest with checksums)."""
