"""Elevation layers: heights at points, relief tiles (hillshade, slope, Terrarium), and the
off-road cost surfaces and routes built on them."""
