// Bootstraps the map: MapLibre from the app's own /vendor route, then imagery, networks, tools.
import { readHeaders, setStatus } from './api.js';
import { BulkEditor } from './bulk.js';
import { Inspector } from './inspector.js';
import { LanePopup } from './lanes.js';
import { Networks, reviewFilter } from './networks.js';
import { loadRasterLayers } from './rasters.js';
import { ReviewTool } from './review.js';
import { RouteTool } from './route.js';
import { Selection, isMultiClick } from './selection.js';
import { TeachTool } from './teach.js';

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

/** The review filter controls: "only confidence below X" (a slider) and "hide edited". */
function setupReviewFilter(networks) {
  const below = document.getElementById('conf-filter');
  const slider = document.getElementById('conf-max');
  const shown = document.getElementById('conf-value');
  const unedited = document.getElementById('hide-edited');
  const apply = () => {
    shown.textContent = Number(slider.value).toFixed(2);
    networks.setFilter(reviewFilter({
      below: below.checked ? Number(slider.value) : null, unedited: unedited.checked,
    }));
  };
  slider.addEventListener('input', () => { below.checked = true; apply(); });
  below.addEventListener('change', apply);
  unedited.addEventListener('change', apply);
  apply();
}

function setupCoordinates(map) {
  const box = document.getElementById('coords');
  map.on('mousemove', (ev) => {
    // lon,lat: the order of the API, `ugvmap route --points` and every error message, so the
    // readout pastes into any of them (it once read lat, lon; issue 34).
    box.textContent = `lon,lat ${ev.lngLat.lng.toFixed(6)},${ev.lngLat.lat.toFixed(6)}  z${map.getZoom().toFixed(1)}`;
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
  setupReviewFilter(networks);
  const route = new RouteTool(map, maplibregl, networks);
  await route.loadProfiles();
  const changed = (names) => {
    for (const name of names) networks.refresh(name);
    route.update(); // the next route must see the edit
  };
  const layers = [...document.querySelectorAll('#raster-layers li[data-layer]')].map((li) => li.dataset.layer);
  const teach = new TeachTool({ map, layers, networks, onAccepted: (name) => changed([name]) });
  const review = new ReviewTool({ map, networks, onChanged: (name) => changed([name]) });
  // The inspector (one segment) and the bulk editor (a selection) share the right dock.
  const layout = () => {
    const docked = !document.getElementById('inspector').hidden || !document.getElementById('bulk').hidden;
    document.body.classList.toggle('dock-open', docked);
    map.resize();
  };
  // A plain click selects one segment, shift-drag boxes and ctrl/shift-clicks add more: one
  // selected segment is shown by the inspector, several by the bulk editor.
  const selection = new Selection({
    map, networks, paused: () => route.isActive() || teach.isActive() || review.isActive(), onChange: (segments) => showSelection(segments),
  });
  const inspector = new Inspector({
    onSaved: (network) => changed([network]),
    onDeleted: (network) => { selection.clear(); changed([network]); },
    onClose: () => selection.clear(),
    onLayout: layout,
    vehicles: () => route.profiles,
  });
  const bulk = new BulkEditor({ selection, onChanged: changed, onClose: () => selection.clear(), onLayout: layout });
  function showSelection(segments) {
    if (segments.length === 1) {
      bulk.hide();
      inspector.open(segments[0].network, segments[0].id);
    } else {
      inspector.hide();
      bulk.show(segments);
    }
  }

  map.on('click', (ev) => {
    if (teach.isActive()) {
      teach.click(ev.lngLat);
      return;
    }
    if (route.isActive()) {
      route.addPoint(ev.lngLat);
      return;
    }
    if (review.isActive()) {
      review.click(ev.point);
      return;
    }
    const hit = networks.segmentAt(ev.point);
    if (hit && isMultiClick(ev)) selection.toggle(hit);
    else if (hit) selection.set([hit]);
    else lanes.show(networks.laneAt(ev.point), ev.lngLat);
  });

  // A painted lane boundary clicked beside its road: what it is, and its kind and colour
  // edited with an editor token.
  const lanes = new LanePopup(map, maplibregl, (name) => changed([name]));
  map.on('mousemove', (ev) => {
    if (route.isActive() || teach.isActive()) return;
    map.getCanvas().style.cursor = networks.segmentAt(ev.point) || networks.laneAt(ev.point) ? 'pointer' : '';
  });

  // A server that refused the networks for want of a token: once one is pasted, reload
  // (the token stays in this tab) so every network layer is built with it.
  document.getElementById('token').addEventListener('change', () => {
    if (networks.refused && document.getElementById('token').value.trim()) window.location.reload();
  });

  const extent = openingView(rasterBounds, networks.extents);
  if (extent && !sharedView) map.fitBounds(extent, { padding: 30, duration: 0, maxZoom: 18 });
  // Exposed for the browser tests and for debugging from the console.
  window.ugvmap = { map, networks, route, inspector, selection, bulk, teach, review, lanes };
  document.body.dataset.ready = 'true';
}

start();
