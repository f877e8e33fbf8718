// Road networks as vector tiles, found like any client would: /networks lists them, each
// network's TileJSON gives the tile URLs and zooms, its MapLibre style the road-class colours.
import { request, describeError, setStatus } from './api.js';

const SPEED_STOPS = [[10, '#d7301f'], [30, '#fc8d59'], [50, '#fee08b'], [70, '#91cf60'], [100, '#1a9850']];
const NO_SPEED_COLOUR = '#8a8a8a';

function speedExpression() {
  return ['case', ['==', ['typeof', ['get', 'speed_limit_kph']], 'number'],
    ['interpolate', ['linear'], ['get', 'speed_limit_kph'], ...SPEED_STOPS.flat()],
    NO_SPEED_COLOUR];
}

/** [label, colour] rows of a style's ['match', input, labels, colour, ..., fallback]. */
function matchRows(expression) {
  const rows = [];
  for (let i = 2; i < expression.length - 1; i += 2) {
    const labels = expression[i];
    rows.push([Array.isArray(labels) ? labels[0] : labels, expression[i + 1]]);
  }
  rows.push(['other', expression[expression.length - 1]]);
  return rows;
}

export function segmentsLayerId(name) { return `net-${name}-segments`; }
function nodesLayerId(name) { return `net-${name}-nodes`; }
function selectedLayerId(name) { return `net-${name}-selected`; }
function sourceId(name) { return `net-${name}`; }

// Networks are drawn from this zoom on: a low-zoom tile would hold a whole city's roads (or
// every network in the database) for lines too small to see, and costs the server most.
export const NETWORK_MINZOOM = 10;

/** Add one network: its tiles as described by its TileJSON, its style's layers renamed for
 * this map, and a highlight layer for the selected segment. */
function addNetwork(map, name, tilejson, style) {
  map.addSource(sourceId(name), {
    type: 'vector', tiles: tilejson.tiles, bounds: tilejson.bounds,
    minzoom: Math.max(tilejson.minzoom, NETWORK_MINZOOM), maxzoom: tilejson.maxzoom,
  });
  const styled = Object.fromEntries(style.layers.map((layer) => [layer['source-layer'], layer]));
  const own = (layer, id) => ({ ...layer, id, source: sourceId(name) });
  map.addLayer(own(styled.segments, segmentsLayerId(name)));
  map.addLayer({
    id: selectedLayerId(name), type: 'line', source: sourceId(name), 'source-layer': 'segments',
    filter: ['==', ['id'], -1],
    paint: { 'line-color': '#00e5ff', 'line-width': ['interpolate', ['linear'], ['zoom'], 10, 4, 16, 9, 19, 16], 'line-opacity': 0.8 },
  });
  map.addLayer(own(styled.nodes, nodesLayerId(name)));
  return styled.segments.paint['line-color'];
}

function legendRows(mode, classColours) {
  const rows = mode === 'speed'
    ? [...SPEED_STOPS.map(([kph, colour]) => [`${kph} km/h`, colour]), ['no limit set', NO_SPEED_COLOUR]]
    : matchRows(classColours);
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
    this.tilejsonUrls = {};
    this.classColours = ['match', ['get', 'road_class'], 'other'];
    this.mode = 'road_class';
    this.refused = false; // the server wants a token to show its networks
  }

  async load() {
    const list = document.getElementById('networks');
    const result = await request('/networks');
    this.refused = result.status === 401 || result.status === 403;
    if (!result.ok) {
      list.innerHTML = '';
      const hint = this.refused ? ' (paste a reader token under Access to see them)' : '';
      setStatus(`Networks: ${describeError(result)}${hint}`);
      return;
    }
    const found = result.body.networks;
    list.innerHTML = found.length ? '' : '<li class="empty">no road networks</li>';
    const described = await Promise.all(found.map((network) => Promise.all(
      [request(network.links.tilejson), request(network.links.style)])));
    for (const [i, network] of found.entries()) {
      const [tilejson, style] = described[i];
      if (!tilejson.ok || !style.ok) {
        setStatus(`${network.name}: ${describeError(tilejson.ok ? style : tilejson)}`);
        continue;
      }
      this.names.push(network.name);
      this.tilejsonUrls[network.name] = network.links.tilejson;
      this.classColours = addNetwork(this.map, network.name, tilejson.body, style.body);
      if (network.bounds) this.extents.push(network.bounds);
      list.appendChild(this.entry(network.name, network.bounds));
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
    const colour = mode === 'speed' ? speedExpression() : this.classColours;
    for (const name of this.names) this.map.setPaintProperty(segmentsLayerId(name), 'line-color', colour);
    document.getElementById('legend').innerHTML = legendRows(mode, this.classColours);
  }

  segmentLayerIds() { return this.names.map(segmentsLayerId); }

  /** Network name and segment id under a screen point (a few pixels of slack), or null. */
  segmentAt(point) {
    const box = [[point.x - 5, point.y - 5], [point.x + 5, point.y + 5]];
    const [feature] = this.map.queryRenderedFeatures(box, { layers: this.segmentLayerIds() });
    if (!feature) return null;
    return { network: feature.layer.id.slice('net-'.length, -'-segments'.length), id: feature.id };
  }

  select(network, id) {
    for (const name of this.names) {
      this.map.setFilter(selectedLayerId(name), ['==', ['id'], name === network ? id : -1]);
    }
  }

  /** After an edit: read the TileJSON again, whose tile URLs name the network's new version
   * (so neither the browser nor a front cache can serve a tile from before the edit). */
  async refresh(network) {
    const tilejson = await request(this.tilejsonUrls[network]);
    if (tilejson.ok) this.map.getSource(sourceId(network)).setTiles(tilejson.body.tiles);
    else setStatus(`${network}: ${describeError(tilejson)}`);
  }
}
