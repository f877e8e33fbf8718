"""The browser map at ``GET /``: a static single-page app over the public HTTP API."""
