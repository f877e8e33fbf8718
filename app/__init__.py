"""ugvmap: imagery → map tiles, road network → routes, for unmanned ground vehicles."""
