# The app image for docker-compose. GDAL comes inside the rasterio wheel; the map library
# comes from the npm registry at the version pinned in app/web/package-lock.json.
FROM node:20-bookworm-slim AS web
WORKDIR /web
COPY app/web/package.json app/web/package-lock.json ./
RUN npm ci --omit=dev

# The front cache (docker-compose service `front-cache`): Debian's nginx with the shipped config.
FROM debian:bookworm-slim AS front-cache
RUN apt-get update && apt-get install -y --no-install-recommends nginx \
    && rm -rf /var/lib/apt/lists/* /etc/nginx/sites-enabled/* \
    && mkdir -p /var/cache/ugvmap && chown www-data:www-data /var/cache/ugvmap
COPY cli/ops/frontcache/nginx.conf /etc/nginx/nginx.conf
COPY cli/ops/frontcache/cache-policy.conf /etc/nginx/ugvmap-cache.conf
EXPOSE 8080
CMD ["nginx", "-g", "daemon off;"]

# The app (the default, last stage).
FROM python:3.11-slim-bookworm
WORKDIR /srv/ugvmap
COPY pyproject.toml README.md alembic.ini ./
COPY app ./app
COPY cli ./cli
COPY ingest ./ingest
COPY migrations ./migrations
# The road model (ONNX, run by onnxruntime; torch is only for training and stays out).
COPY models ./models
# Installed in place: the web router serves app/web/node_modules next to its own files.
RUN pip install --no-cache-dir -e .
# Routing's compiled kernels (numba, app/routing/native.py) into the image's numba cache, so
# no container compiles them at start.
RUN python -c "import app.routing.planner"
COPY --from=web /web/node_modules ./app/web/node_modules
ENV UGVMAP_RASTER_STORE=/data/rasters UGVMAP_DATA_DIR=/data
EXPOSE 8000
CMD ["sh", "-c", "ugvmap db upgrade && ugvmap serve --host 0.0.0.0 --port 8000 --workers 2"]
