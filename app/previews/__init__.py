"""Road previews: a window of a raster layer re-extracted with the layer's labels (a job the
workers run), shown before anything enters a network, and accepted into one on request."""
