"""Lane-level Lanelet2 maps (OSM XML, Autoware conventions) generated from a road network.

One lanelet per lane and allowed direction of every segment, connecting lanelets for every
allowed movement at junctions, traffic-light regulatory elements with stop lines; every
lanelet tagged ``segment_id`` so a lanelet route maps back to the network. The geometry steps
are pure functions (:mod:`app.lanelet2.geometry`), the per-node rules in
:mod:`app.lanelet2.topology`, the file in :mod:`app.lanelet2.osm_xml`.
"""
