// Road networks as vector tiles, found like any client would: /networks lists them, each
// network's TileJSON gives the tile URLs and zooms, its MapLibre style the road-class colours.
// The map adds what only an editor needs: one-way arrows, colour by speed or by extraction
// confidence, a "confidence below X" filter and the highlight of selected segments.
import { request, describeError, setStatus } from './api.js';

const SPEED_STOPS = [[10, '#d7301f'], [30, '#fc8d59'], [50, '#fee08b'], [70, '#91cf60'], [100, '#1a9850']];
const NO_SPEED_COLOUR = '#8a8a8a';
// Extraction confidence (0..1): red where the model was unsure, green where it was sure.
export const CONFIDENCE_STOPS = [[0, '#d7191c'], [0.5, '#fdae61'], [0.75, '#ffffbf'], [1, '#1a9641']];
const NOT_EXTRACTED_COLOUR = '#8a8a8a';
const ARROW_IMAGE = 'ugvmap-oneway';
// Arrows from this zoom on: below it a one-way street is a few pixels long.
const ARROWS_MINZOOM = 15;

function rampExpression(property, stops, missing) {
  return ['case', ['==', ['typeof', ['get', property]], 'number'],
    ['interpolate', ['linear'], ['get', property], ...stops.flat()],
    missing];
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
function casingLayerId(name) { return `net-${name}-segments-casing`; }
export function arrowsLayerId(name) { return `net-${name}-oneway`; }
function styleLayerId(name, styleId) { return `net-${name}-${styleId}`; }
function selectedLayerId(name) { return `net-${name}-selected`; }
function sourceId(name) { return `net-${name}`; }

// Networks are drawn from this zoom on: a low-zoom tile would hold a whole city's roads (or
// every network in the database) for lines too small to see, and costs the server most.
export const NETWORK_MINZOOM = 10;

/** A chevron pointing along the line (+x), white with a dark rim like the road casing, drawn
 * once: the page loads no sprite sheet (nothing is fetched from outside the server). */
function arrowImage() {
  const size = 32; // drawn at pixelRatio 2: 16 css px
  const canvas = document.createElement('canvas');
  canvas.width = canvas.height = size;
  const ctx = canvas.getContext('2d');
  ctx.beginPath();
  ctx.moveTo(9, 7);
  ctx.lineTo(24, 16);
  ctx.lineTo(9, 25);
  ctx.lineJoin = 'round';
  ctx.lineCap = 'round';
  ctx.strokeStyle = '#1d2329';
  ctx.lineWidth = 8;
  ctx.stroke();
  ctx.strokeStyle = '#ffffff';
  ctx.lineWidth = 4;
  ctx.stroke();
  return ctx.getImageData(0, 0, size, size);
}

/** Add one network: its tiles as described by its TileJSON, its style's layers renamed for
 * this map, one-way arrows, and a highlight layer for the selected segments; the painted lane
 * boundaries (from z16, as the style draws them) over the roads. Returns the road-class
 * colours and the ids of the node and lane layers. */
function addNetwork(map, name, tilejson, style) {
  map.addSource(sourceId(name), {
    type: 'vector', tiles: tilejson.tiles, bounds: tilejson.bounds,
    minzoom: Math.max(tilejson.minzoom, NETWORK_MINZOOM), maxzoom: tilejson.maxzoom,
  });
  const styled = Object.fromEntries(style.layers.map((layer) => [layer.id, layer]));
  const own = (layer, id) => ({ ...layer, id, source: sourceId(name) });
  map.addLayer(own(styled['segments-casing'], casingLayerId(name)));
  // The selection is a halo under the road, so its colour (class, speed, confidence) still shows.
  map.addLayer({
    id: selectedLayerId(name), type: 'line', source: sourceId(name), 'source-layer': 'segments',
    filter: ['in', ['id'], ['literal', []]],
    layout: { 'line-cap': 'round', 'line-join': 'round' },
    paint: { 'line-color': '#00e5ff', 'line-width': ['interpolate', ['linear'], ['zoom'], 10, 7, 16, 15, 19, 24] },
  });
  map.addLayer(own(styled.segments, segmentsLayerId(name)));
  map.addLayer({
    id: arrowsLayerId(name), type: 'symbol', source: sourceId(name), 'source-layer': 'segments',
    minzoom: ARROWS_MINZOOM, filter: ['!=', ['get', 'oneway'], 'none'],
    layout: {
      'symbol-placement': 'line', 'symbol-spacing': 60, 'icon-image': ARROW_IMAGE,
      // The chevron points along the geometry; a backward one-way runs against it.
      'icon-rotate': ['case', ['==', ['get', 'oneway'], 'backward'], 180, 0],
      'icon-rotation-alignment': 'map', 'icon-allow-overlap': true, 'icon-ignore-placement': true,
    },
  });
  // Nodes come as one style layer per kind (junctions, traffic lights, plain nodes), each
  // with fixed colours, the form QGIS's style converter also reads.
  const nodeLayers = style.layers.filter((l) => l['source-layer'] === 'nodes')
    .map((layer) => styleLayerId(name, layer.id));
  style.layers.filter((l) => l['source-layer'] === 'nodes')
    .forEach((layer, i) => map.addLayer(own(layer, nodeLayers[i])));
  const laneLayers = style.layers.filter((l) => l['source-layer'] === 'lanes')
    .map((layer) => styleLayerId(name, layer.id));
  style.layers.filter((l) => l['source-layer'] === 'lanes')
    .forEach((layer, i) => map.addLayer(own(layer, laneLayers[i])));
  return { classColours: styled.segments.paint['line-color'], nodeLayers, laneLayers };
}

function legendRows(mode, classColours) {
  if (mode === 'speed') {
    return [...SPEED_STOPS.map(([kph, colour]) => [`${kph} km/h`, colour]), ['no limit set', NO_SPEED_COLOUR]];
  }
  if (mode === 'confidence') {
    return [...CONFIDENCE_STOPS.map(([value, colour]) => [`confidence ${value.toFixed(2)}`, colour]),
      ['not extracted', NOT_EXTRACTED_COLOUR]];
  }
  return matchRows(classColours);
}

function legendHtml(mode, classColours) {
  const lines = legendRows(mode, classColours)
    .map(([label, colour]) => `<li><i class="swatch" style="background:${colour}"></i>${label}</li>`);
  lines.push('<li><i class="dot" style="background:#ff9800"></i>junction</li>');
  lines.push('<li><i class="dot light"></i>traffic light</li>');
  lines.push('<li><i class="arrow">›</i>one-way</li>');
  lines.push('<li><i class="swatch lane"></i>lane lines from the paint (zoom 16+)</li>');
  return `<ul>${lines.join('')}</ul>`;
}

/** The layer filter for a review: only segments below a confidence (extracted ones: a segment
 * without confidence was not extracted), and/or only those nobody has edited yet. */
export function reviewFilter({ below = null, unedited = false } = {}) {
  const parts = [];
  // Not extracted (null) counts as 2, never below any threshold.
  if (below !== null) parts.push(['<', ['coalesce', ['get', 'confidence'], 2], below]);
  if (unedited) parts.push(['<=', ['get', 'version'], 1]);
  return parts.length ? ['all', ...parts] : null;
}

/** The network layer group: list, styling, filters, selection highlight, tile refresh. */
export class Networks {
  constructor(map) {
    this.map = map;
    this.names = [];
    this.extents = [];
    this.bounds = {};
    this.tilejsonUrls = {};
    this.nodeLayers = {};
    this.laneLayers = {};
    this.classColours = ['match', ['get', 'road_class'], 'other'];
    this.mode = 'road_class';
    this.filter = null;
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
    this.map.addImage(ARROW_IMAGE, arrowImage(), { pixelRatio: 2 });
    for (const [i, network] of found.entries()) {
      const [tilejson, style] = described[i];
      if (!tilejson.ok || !style.ok) {
        setStatus(`${network.name}: ${describeError(tilejson.ok ? style : tilejson)}`);
        continue;
      }
      this.names.push(network.name);
      this.tilejsonUrls[network.name] = network.links.tilejson;
      const added = addNetwork(this.map, network.name, tilejson.body, style.body);
      this.classColours = added.classColours;
      this.nodeLayers[network.name] = added.nodeLayers;
      this.laneLayers[network.name] = added.laneLayers;
      if (network.bounds) {
        this.extents.push(network.bounds);
        this.bounds[network.name] = network.bounds;
      }
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
      for (const id of this.layerIds(name)) this.map.setLayoutProperty(id, 'visibility', visibility);
    });
    const zoom = li.querySelector('.zoom');
    // Zooming to a network picks it for routing too: the map centre may then lie in a smaller
    // network's bounds, which the route tool would otherwise follow (issue 34).
    if (bbox) zoom.addEventListener('click', () => {
      this.map.fire('ugvmap.networkzoom', { network: name });
      this.map.fitBounds(bbox, { padding: 20, maxZoom: 18 });
    });
    else zoom.disabled = true;
    return li;
  }

  layerIds(name) {
    return [casingLayerId(name), segmentsLayerId(name), selectedLayerId(name), arrowsLayerId(name),
      ...this.nodeLayers[name], ...this.laneLayers[name]];
  }

  setMode(mode) {
    this.mode = mode;
    const colour = mode === 'speed' ? rampExpression('speed_limit_kph', SPEED_STOPS, NO_SPEED_COLOUR)
      : mode === 'confidence' ? rampExpression('confidence', CONFIDENCE_STOPS, NOT_EXTRACTED_COLOUR)
        : this.classColours;
    for (const name of this.names) this.map.setPaintProperty(segmentsLayerId(name), 'line-color', colour);
    document.getElementById('legend').innerHTML = legendHtml(mode, this.classColours);
  }

  /** Show only the segments a review filter keeps (null: all). The selection highlight is
   * not filtered: whatever a bulk action would change stays in sight. */
  setFilter(filter) {
    this.filter = filter;
    for (const name of this.names) {
      this.map.setFilter(casingLayerId(name), filter);
      this.map.setFilter(segmentsLayerId(name), filter);
      const oneway = ['!=', ['get', 'oneway'], 'none'];
      this.map.setFilter(arrowsLayerId(name), filter ? ['all', oneway, filter] : oneway);
    }
  }

  segmentLayerIds() { return this.names.map(segmentsLayerId); }

  /** What a click or box needs of a drawn segment feature: its network, id and version. */
  static segmentOf(feature) {
    return {
      network: feature.layer.id.slice('net-'.length, -'-segments'.length),
      id: feature.id,
      version: feature.properties.version,
    };
  }

  /** The segment under a screen point (a few pixels of slack), or null. */
  segmentAt(point) {
    const box = [[point.x - 5, point.y - 5], [point.x + 5, point.y + 5]];
    const [feature] = this.map.queryRenderedFeatures(box, { layers: this.segmentLayerIds() });
    return feature ? Networks.segmentOf(feature) : null;
  }

  /** The painted lane boundary under a screen point ({network, id, properties}), or null. */
  laneAt(point) {
    const box = [[point.x - 4, point.y - 4], [point.x + 4, point.y + 4]];
    const layers = this.names.flatMap((name) => this.laneLayers[name]);
    const [feature] = layers.length ? this.map.queryRenderedFeatures(box, { layers }) : [];
    if (!feature) return null;
    const network = this.names.find((name) => this.laneLayers[name].includes(feature.layer.id));
    return { network, id: feature.id, properties: feature.properties };
  }

  /** Every drawn segment meeting a screen box, once each (a segment cut by tile borders is
   * drawn as several features). */
  segmentsIn(box) {
    const found = new Map();
    for (const feature of this.map.queryRenderedFeatures(box, { layers: this.segmentLayerIds() })) {
      const segment = Networks.segmentOf(feature);
      found.set(`${segment.network}/${segment.id}`, segment);
    }
    return [...found.values()];
  }

  /** Highlight the selected segments ({network, id} items). */
  highlight(segments) {
    for (const name of this.names) {
      const ids = segments.filter((s) => s.network === name).map((s) => s.id);
      this.map.setFilter(selectedLayerId(name), ['in', ['id'], ['literal', ids]]);
    }
  }

  /** The network whose bounds hold a point, the smallest when several do (a small survey
   * network inside a city's); null when none does. */
  networkAt(lngLat) {
    const area = (b) => (b[2] - b[0]) * (b[3] - b[1]);
    const holding = Object.entries(this.bounds).filter(([, b]) => b[0] <= lngLat.lng && lngLat.lng <= b[2]
      && b[1] <= lngLat.lat && lngLat.lat <= b[3]);
    if (!holding.length) return null;
    return holding.reduce((a, b) => (area(b[1]) < area(a[1]) ? b : a))[0];
  }

  /** After an edit: read the TileJSON again, whose tile URLs name the network's new version
   * (so neither the browser nor a front cache can serve a tile from before the edit). */
  async refresh(network) {
    const tilejson = await request(this.tilejsonUrls[network]);
    if (tilejson.ok) this.map.getSource(sourceId(network)).setTiles(tilejson.body.tiles);
    else setStatus(`${network}: ${describeError(tilejson)}`);
  }
}
