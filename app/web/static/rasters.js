// Raster layer panel: one entry per /layers item, drawn from its TileJSON (bounds, zooms).
import { request, describeError, setStatus } from './api.js';

function rasterLayerId(slug) { return `raster-${slug}`; }

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
    map.addLayer({ id: rasterLayerId(layer.slug), type: 'raster', source: rasterLayerId(layer.slug) });
    list.appendChild(entry(map, layer, tilejson));
    bounds.push(tilejson.bounds);
  }
  return bounds;
}
