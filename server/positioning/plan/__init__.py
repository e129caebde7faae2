"""Floor plans: the GeoJSON plan format (``geojson_plan``), the walkable raster and the
wall-crossing test (``floor_plan``, ``wall_index``), the navigation graph of reference
points (``navigation_graph``) and the anchors a plan marks (``anchors``)."""
