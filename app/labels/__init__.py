"""A raster layer's labels (road / not road), which road extraction learns from."""
