// Bootstraps the map: MapLibre from the app's own /vendor route, then imagery, networks, tools.
import { readHeaders, setStatus } from './api.js';
import { Inspector } from './inspector.js';
import { Networks } from './networks.js';
import { loadRasterLayers } from './rasters.js';
import { RouteTool } from './route.js';

// A style with no glyphs or sprites: nothing is fetched from outside this server.
const STYLE = {
  version: 8,
  sources: {},
  layers: [{ id: 'background', type: 'background', paint: { 'background-color': '#e9ecef' } }],
};

function union(boxes) {
  if (!boxes.length) return null;
  return boxes.reduce((a, b) => [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[2], b[2]), Math.max(a[3], b[3])]);
}

function meets(a, b) {
  return a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3];
}

/**
 * Where the map opens when the URL carries no view: the smallest imagery layer that has a
 * road network on it (where there is something to inspect and route), else everything.
 * Sample data spread over several continents would otherwise open on an empty world.
 */
function openingView(rasterBounds, networkExtents) {
  const area = (b) => (b[2] - b[0]) * (b[3] - b[1]);
  const covered = rasterBounds.filter((r) => networkExtents.some((n) => meets(r, n)));
  if (covered.length) return covered.reduce((a, b) => (area(b) < area(a) ? b : a));
  return union([...networkExtents, ...rasterBounds]);
}

function setupPanelToggle(map) {
  const button = document.getElementById('panel-toggle');
  const narrow = window.matchMedia('(max-width: 700px)');
  const apply = (open) => {
    document.body.classList.toggle('panel-closed', !open);
    button.setAttribute('aria-expanded', String(open));
    map.resize();
  };
  apply(!narrow.matches);
  button.addEventListener('click', () => apply(document.body.classList.contains('panel-closed')));
  narrow.addEventListener('change', () => apply(!narrow.matches));
}

function setupCoordinates(map) {
  const box = document.getElementById('coords');
  map.on('mousemove', (ev) => {
    box.textContent = `${ev.lngLat.lat.toFixed(6)}, ${ev.lngLat.lng.toFixed(6)}  z${map.getZoom().toFixed(1)}`;
  });
}

async function start() {
  let maplibregl;
  try {
    maplibregl = await import('/vendor/maplibre-gl/maplibre-gl.mjs');
  } catch (err) {
    setStatus('Map library missing: run scripts/setup.sh (npm ci in app/web).');
    throw err;
  }
  // hash: the view lives in the URL (#map=zoom/lat/lon), so a view can be shared or reloaded.
  // Read before the map exists: the map writes its own view into the hash at once.
  const sharedView = window.location.hash.includes('map=');
  const map = new maplibregl.Map({
    container: 'map', style: STYLE, center: [0, 0], zoom: 1, attributionControl: false,
    hash: 'map',
    // Tiles of networks that need a reader token get it, as the JSON reads do (api.js).
    transformRequest: (url) => ({ url, headers: readHeaders(url) }),
  });
  map.addControl(new maplibregl.NavigationControl({ showCompass: false }), 'top-right');
  map.addControl(new maplibregl.ScaleControl({ unit: 'metric', maxWidth: 120 }), 'bottom-right');
  map.on('error', (ev) => setStatus(ev.error?.message || 'map error'));
  setupPanelToggle(map);
  setupCoordinates(map);
  await new Promise((resolve) => map.on('load', resolve));

  const rasterBounds = await loadRasterLayers(map);
  const networks = new Networks(map);
  await networks.load();
  const route = new RouteTool(map, maplibregl, networks.names);
  const inspector = new Inspector({
    onSaved: (network) => {
      networks.refresh(network);
      route.update(); // the next route must see the edit
    },
    onClose: () => networks.select(null, -1),
    onLayout: () => map.resize(),
  });

  map.on('click', (ev) => {
    if (route.isActive()) {
      route.addPoint(ev.lngLat);
      return;
    }
    const hit = networks.segmentAt(ev.point);
    if (!hit) return;
    networks.select(hit.network, hit.id);
    inspector.open(hit.network, hit.id);
  });
  map.on('mousemove', (ev) => {
    if (route.isActive()) return;
    map.getCanvas().style.cursor = networks.segmentAt(ev.point) ? 'pointer' : '';
  });

  // A server that refused the networks for want of a token: once one is pasted, reload
  // (the token stays in this tab) so every network layer is built with it.
  document.getElementById('token').addEventListener('change', () => {
    if (networks.refused && document.getElementById('token').value.trim()) window.location.reload();
  });

  const extent = openingView(rasterBounds, networks.extents);
  if (extent && !sharedView) map.fitBounds(extent, { padding: 30, duration: 0, maxZoom: 18 });
  // Exposed for the browser tests and for debugging from the console.
  window.ugvmap = { map, networks, route, inspector };
  document.body.dataset.ready = 'true';
}

start();
