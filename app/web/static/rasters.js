// Raster layer panel: one entry per /layers item, drawn from its TileJSON (bounds, zooms).
// An elevation layer is drawn as a hillshade overlay (or its slope ramp, with the legend) and
// can lift the map into 3D from its Terrarium tiles (MapLibre's raster-dem).
import { request, describeError, setStatus } from './api.js';

function rasterLayerId(slug) { return `raster-${slug}`; }
function demSourceId(slug) { return `dem-${slug}`; }
const TERRAIN_EXAGGERATION = 1.5;
const OVERLAY_OPACITY = 0.6; // a hillshade over the imagery, not instead of it

function legend(stops) {
  const gradient = stops.map((s, i) => `${s.colour} ${(100 * i) / (stops.length - 1)}%`).join(', ');
  const div = document.createElement('div');
  div.className = 'slope-legend';
  div.hidden = true;
  div.innerHTML = `<div class="ramp" style="background: linear-gradient(to right, ${gradient})"></div>
    <div class="ticks">${stops.map((s) => `<span>${s.degrees}°</span>`).join('')}</div>`;
  return div;
}

/** The 3D toggle and the hillshade / slope choice of an elevation layer's entry. */
function terrainControls(map, layer, tilejson, li) {
  const id = rasterLayerId(layer.slug);
  const dem = demSourceId(layer.slug);
  const row = document.createElement('div');
  row.className = 'row controls terrain';
  row.innerHTML = `<label><input type="checkbox" class="terrain-3d"> 3D terrain</label>
    <select class="render" aria-label="relief"><option value="hillshade">hillshade</option>
      <option value="slope">slope</option></select>`;
  const key = legend(layer.renders.slope_legend);
  li.append(row, key);
  row.querySelector('.terrain-3d').addEventListener('change', (ev) => {
    if (ev.target.checked) {
      if (!map.getSource(dem)) {
        map.addSource(dem, {
          type: 'raster-dem', tiles: [layer.renders.terrarium.tiles], tileSize: 256,
          encoding: 'terrarium', bounds: tilejson.bounds, minzoom: tilejson.minzoom,
          maxzoom: tilejson.maxzoom,
        });
      }
      map.setTerrain({ source: dem, exaggeration: TERRAIN_EXAGGERATION });
      map.easeTo({ pitch: 60, duration: 0 });
    } else {
      map.setTerrain(null);
      map.easeTo({ pitch: 0, duration: 0 });
    }
    document.body.dataset.terrain = ev.target.checked ? layer.slug : '';
  });
  row.querySelector('.render').addEventListener('change', (ev) => {
    map.getSource(id).setTiles([layer.renders[ev.target.value].tiles]);
    key.hidden = ev.target.value !== 'slope';
  });
}

function entry(map, layer, tilejson) {
  const id = rasterLayerId(layer.slug);
  const li = document.createElement('li');
  li.dataset.layer = layer.slug;
  li.innerHTML = `
    <label class="row"><input type="checkbox" class="visible" checked>
      <span class="title"></span></label>
    <div class="row controls">
      <input type="range" class="opacity" min="0" max="100" value="100" aria-label="opacity">
      <button type="button" class="zoom" title="Zoom to the layer's extent">Zoom</button>
    </div>`;
  li.querySelector('.title').textContent = `${layer.title} (${layer.kind})`;
  li.querySelector('.visible').addEventListener('change', (ev) => {
    map.setLayoutProperty(id, 'visibility', ev.target.checked ? 'visible' : 'none');
  });
  li.querySelector('.opacity').addEventListener('input', (ev) => {
    map.setPaintProperty(id, 'raster-opacity', Number(ev.target.value) / 100);
  });
  li.querySelector('.zoom').addEventListener('click', () => {
    map.fitBounds(tilejson.bounds, { padding: 20, maxZoom: tilejson.maxzoom });
  });
  if (layer.kind === 'elevation' && layer.renders) {
    li.querySelector('.opacity').value = String(OVERLAY_OPACITY * 100);
    terrainControls(map, layer, tilejson, li);
  }
  return li;
}

/** Add every raster layer to the map (below the vector layers) and list it; returns their bounds. */
export async function loadRasterLayers(map) {
  const list = document.getElementById('raster-layers');
  const result = await request('/layers');
  if (!result.ok) {
    list.innerHTML = '';
    setStatus(`Imagery: ${describeError(result)}`);
    return [];
  }
  list.innerHTML = result.body.layers.length ? '' : '<li class="empty">no raster layers</li>';
  const bounds = [];
  const tilejsons = await Promise.all(result.body.layers.map((layer) => request(layer.links.tilejson)));
  for (const [i, layer] of result.body.layers.entries()) {
    const tj = tilejsons[i];
    if (!tj.ok) {
      setStatus(`${layer.slug}: ${describeError(tj)}`);
      continue;
    }
    const tilejson = tj.body;
    map.addSource(rasterLayerId(layer.slug), {
      type: 'raster', tiles: tilejson.tiles, tileSize: 256, bounds: tilejson.bounds,
      minzoom: tilejson.minzoom, maxzoom: tilejson.maxzoom, attribution: tilejson.attribution,
    });
    map.addLayer({
      id: rasterLayerId(layer.slug), type: 'raster', source: rasterLayerId(layer.slug),
      paint: { 'raster-opacity': layer.kind === 'elevation' ? OVERLAY_OPACITY : 1 },
    });
    list.appendChild(entry(map, layer, tilejson));
    bounds.push(tilejson.bounds);
  }
  return bounds;
}
