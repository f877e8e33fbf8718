// Road networks as vector tiles: segments coloured by road class or speed limit, nodes by kind.
import { request, describeError, setStatus } from './api.js';

const SUFFIX = '-segments';

export const ROAD_CLASS_COLOURS = [
  ['motorway', '#e8308a'], ['trunk', '#f0642a'], ['primary', '#f5a623'],
  ['secondary', '#e6d23c'], ['tertiary', '#8fd14f'], ['residential', '#4fb5d1'],
  ['service', '#9b8fd1'], ['track', '#a0764a'],
];
const OTHER_COLOUR = '#5a6b7a';
const SPEED_STOPS = [[10, '#d7301f'], [30, '#fc8d59'], [50, '#fee08b'], [70, '#91cf60'], [100, '#1a9850']];
const NO_SPEED_COLOUR = '#8a8a8a';

function classExpression() {
  const match = ['match', ['get', 'road_class']];
  for (const [cls, colour] of ROAD_CLASS_COLOURS) match.push([cls, `${cls}_link`], colour);
  match.push(OTHER_COLOUR);
  return match;
}

function speedExpression() {
  return ['case', ['==', ['typeof', ['get', 'speed_limit_kph']], 'number'],
    ['interpolate', ['linear'], ['get', 'speed_limit_kph'], ...SPEED_STOPS.flat()],
    NO_SPEED_COLOUR];
}

export function segmentsLayerId(name) { return `net-${name}-segments`; }
function nodesLayerId(name) { return `net-${name}-nodes`; }
function selectedLayerId(name) { return `net-${name}-selected`; }
function sourceId(name) { return `net-${name}`; }

function tileUrl(name, stamp) {
  return `${location.origin}/networks/${encodeURIComponent(name)}/tiles/{z}/{x}/{y}.mvt?v=${stamp}`;
}

// Networks are drawn from this zoom on: a low-zoom tile would hold a whole city's roads (or
// every network in the database) for lines too small to see, and costs the server most.
export const NETWORK_MINZOOM = 10;

/** A value per node kind: traffic light, junction, other. */
function nodeValue(light, junction, other) {
  return ['case', ['get', 'traffic_light'], light, ['==', ['get', 'kind'], 'junction'], junction, other];
}

function addNetwork(map, name) {
  map.addSource(sourceId(name), {
    type: 'vector', tiles: [tileUrl(name, Date.now())], minzoom: NETWORK_MINZOOM, maxzoom: 18,
  });
  map.addLayer({
    id: segmentsLayerId(name), type: 'line', source: sourceId(name), 'source-layer': 'segments',
    layout: { 'line-cap': 'round', 'line-join': 'round' },
    paint: {
      'line-color': classExpression(),
      'line-width': ['interpolate', ['linear'], ['zoom'], 10, 1.5, 16, 5, 19, 10],
    },
  });
  map.addLayer({
    id: selectedLayerId(name), type: 'line', source: sourceId(name), 'source-layer': 'segments',
    filter: ['==', ['id'], -1],
    paint: { 'line-color': '#00e5ff', 'line-width': ['interpolate', ['linear'], ['zoom'], 10, 4, 16, 9, 19, 16], 'line-opacity': 0.8 },
  });
  map.addLayer({
    id: nodesLayerId(name), type: 'circle', source: sourceId(name), 'source-layer': 'nodes',
    paint: {
      // Traffic lights: big red with a white ring; junctions: orange; plain (degree-2) nodes:
      // small grey, only from z16 where they no longer crowd the roads. Zoom must be the input
      // of the top-level step, so the kind cases repeat on both sides of it.
      'circle-radius': ['step', ['zoom'], nodeValue(6, 4, 0), 16, nodeValue(6, 4, 2.5)],
      'circle-stroke-width': ['step', ['zoom'], nodeValue(2, 1, 0), 16, nodeValue(2, 1, 1)],
      'circle-color': nodeValue('#e02020', '#ff9800', '#607080'),
      'circle-stroke-color': '#ffffff',
    },
  });
}

function legendRows(mode) {
  const rows = mode === 'speed'
    ? [...SPEED_STOPS.map(([kph, colour]) => [`${kph} km/h`, colour]), ['no limit set', NO_SPEED_COLOUR]]
    : [...ROAD_CLASS_COLOURS, ['other', OTHER_COLOUR]];
  const lines = rows.map(([label, colour]) => `<li><i class="swatch" style="background:${colour}"></i>${label}</li>`);
  lines.push('<li><i class="dot" style="background:#ff9800"></i>junction</li>');
  lines.push('<li><i class="dot light"></i>traffic light</li>');
  return `<ul>${lines.join('')}</ul>`;
}

/** The network layer group: list, styling, selection highlight and tile refresh after edits. */
export class Networks {
  constructor(map) {
    this.map = map;
    this.names = [];
    this.extents = [];
    this.mode = 'road_class';
  }

  async load() {
    const list = document.getElementById('networks');
    const result = await request('/collections');
    if (!result.ok) {
      list.innerHTML = '';
      setStatus(`Networks: ${describeError(result)}`);
      return;
    }
    const segmentCollections = result.body.collections.filter((c) => c.id.endsWith(SUFFIX));
    list.innerHTML = segmentCollections.length ? '' : '<li class="empty">no road networks</li>';
    for (const collection of segmentCollections) {
      const name = collection.id.slice(0, -SUFFIX.length);
      this.names.push(name);
      addNetwork(this.map, name);
      const bbox = collection.extent?.spatial?.bbox?.[0];
      if (bbox) this.extents.push(bbox);
      list.appendChild(this.entry(name, bbox));
    }
    const hint = document.getElementById('net-hint');
    const showHint = () => { hint.hidden = !this.names.length || this.map.getZoom() >= NETWORK_MINZOOM; };
    this.map.on('zoomend', showHint);
    showHint();
    const select = document.getElementById('net-style');
    select.addEventListener('change', () => this.setMode(select.value));
    this.setMode(select.value);
  }

  entry(name, bbox) {
    const li = document.createElement('li');
    li.dataset.network = name;
    li.innerHTML = `<label class="row"><input type="checkbox" class="visible" checked><span class="title"></span></label>
      <div class="row controls"><button type="button" class="zoom">Zoom</button></div>`;
    li.querySelector('.title').textContent = name;
    li.querySelector('.visible').addEventListener('change', (ev) => {
      const visibility = ev.target.checked ? 'visible' : 'none';
      for (const id of [segmentsLayerId(name), selectedLayerId(name), nodesLayerId(name)]) {
        this.map.setLayoutProperty(id, 'visibility', visibility);
      }
    });
    const zoom = li.querySelector('.zoom');
    if (bbox) zoom.addEventListener('click', () => this.map.fitBounds(bbox, { padding: 20, maxZoom: 18 }));
    else zoom.disabled = true;
    return li;
  }

  setMode(mode) {
    this.mode = mode;
    const colour = mode === 'speed' ? speedExpression() : classExpression();
    for (const name of this.names) this.map.setPaintProperty(segmentsLayerId(name), 'line-color', colour);
    document.getElementById('legend').innerHTML = legendRows(mode);
  }

  segmentLayerIds() { return this.names.map(segmentsLayerId); }

  /** Network name and segment id under a screen point (a few pixels of slack), or null. */
  segmentAt(point) {
    const box = [[point.x - 5, point.y - 5], [point.x + 5, point.y + 5]];
    const [feature] = this.map.queryRenderedFeatures(box, { layers: this.segmentLayerIds() });
    if (!feature) return null;
    return { network: feature.layer.id.slice('net-'.length, -SUFFIX.length), id: feature.id };
  }

  select(network, id) {
    for (const name of this.names) {
      this.map.setFilter(selectedLayerId(name), ['==', ['id'], name === network ? id : -1]);
    }
  }

  /** Re-request the network's tiles (new URL, so no cached tile survives) after an edit. */
  refresh(network) {
    this.map.getSource(sourceId(network)).setTiles([tileUrl(network, Date.now())]);
  }
}
