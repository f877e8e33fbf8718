"""The service as standard clients meet it: the OGC landing page and conformance, the OpenAPI
3.0 document, and the HTTP behaviour every endpoint shares (HEAD, CORS, gzip)."""
