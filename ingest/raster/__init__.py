"""Raster ingest: survey imagery in, Cloud-Optimized GeoTIFFs on the web-mercator grid out.

Steps, each a module: ``georef`` (where the pixels are: from the file, a world file, a zone
sidecar or ground control points), ``sources`` (validate the input and describe it as a GDAL
VRT with an explicit mask), ``cog`` (GDAL's COG driver writes the pyramid, atomically),
``footprint`` (the covered area, for the tile query) and ``job`` (the whole ingest, with the
catalogue rows committed only after every file exists).
"""
