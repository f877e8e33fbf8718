# The app image for docker-compose. GDAL comes inside the rasterio wheel.
FROM python:3.11-slim-bookworm
WORKDIR /srv/ugvmap
COPY pyproject.toml README.md alembic.ini ./
COPY app ./app
COPY ingest ./ingest
COPY migrations ./migrations
RUN pip install --no-cache-dir .
ENV UGVMAP_RASTER_STORE=/data/rasters
EXPOSE 8000
CMD ["sh", "-c", "ugvmap db upgrade && ugvmap serve --host 0.0.0.0 --port 8000 --workers 2"]
