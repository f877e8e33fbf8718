// Route tool: task points as draggable markers, OSRM-shaped route from /networks/{name}/route.
import { request, describeError } from './api.js';

const ROUTE_SOURCE = 'route';

export function formatDistance(m) {
  return m >= 1000 ? `${(m / 1000).toFixed(2)} km` : `${Math.round(m)} m`;
}

export function formatDuration(s) {
  const minutes = Math.floor(s / 60);
  const seconds = Math.round(s - minutes * 60);
  return minutes ? `${minutes} min ${seconds} s` : `${seconds} s`;
}

/** The step's maneuver in words, as OSRM's types and modifiers read (e.g. "new name" is a
 * road changing its name going straight: "Continue"). */
function verbOf({ type, modifier, exit }) {
  const turn = modifier && modifier !== 'straight' ? ` ${modifier}` : '';
  switch (type) {
    case 'depart': return 'Depart';
    case 'turn': case 'end of road': case 'fork': return `Turn${turn || ' straight'}`;
    case 'new name': case 'continue': return modifier === 'uturn' ? 'Make a U-turn' : `Continue${turn}`;
    case 'roundabout': case 'rotary': return `Enter the roundabout${exit ? `, exit ${exit}` : ''}`;
    case 'exit roundabout': case 'exit rotary': return 'Leave the roundabout';
    default: return `${type[0].toUpperCase()}${type.slice(1)}${turn}`;
  }
}

function stepText(step) {
  const road = step.name ? ` on ${step.name}` : '';
  const limit = step.speed_limit_kph ? `, ${step.speed_limit_kph} km/h` : '';
  if (step.maneuver.type === 'arrive') return 'Arrive';
  return `${verbOf(step.maneuver)}${road} — ${formatDistance(step.distance)}${limit}`;
}

/** A failed route in words: the server's message names the points as the markers number
 * them (from 1); a route that found no connection says so itself. */
function routeError(result) {
  const message = describeError(result);
  if (result.body?.code === 'NoRoute') return `${message[0].toUpperCase()}${message.slice(1)}.`;
  return `No route: ${message}`;
}

/** Click-to-add task points and the drawn route; active only while its checkbox is ticked.
 * The network routed on follows the map (the one on screen) until the user picks one or
 * places a point. */
export class RouteTool {
  constructor(map, maplibregl, networks) {
    this.map = map;
    this.maplibregl = maplibregl;
    this.networks = networks;
    this.markers = [];
    this.active = document.getElementById('route-active');
    this.optimize = document.getElementById('route-optimize');
    this.network = document.getElementById('route-network');
    this.result = document.getElementById('route-result');
    this.network.replaceChildren(...networks.names.map((n) => new Option(n, n)));
    this.picked = false; // the user chose the network in the list
    this.followView();
    map.on('moveend', () => this.followView());
    this.requestSeq = 0;
    map.addSource(ROUTE_SOURCE, { type: 'geojson', data: { type: 'FeatureCollection', features: [] } });
    map.addLayer({ id: 'route-casing', type: 'line', source: ROUTE_SOURCE,
      layout: { 'line-cap': 'round', 'line-join': 'round' },
      paint: { 'line-color': '#ffffff', 'line-width': 9 } });
    map.addLayer({ id: 'route-line', type: 'line', source: ROUTE_SOURCE,
      layout: { 'line-cap': 'round', 'line-join': 'round' },
      paint: { 'line-color': '#1f4fff', 'line-width': 5 } });
    this.optimize.addEventListener('change', () => this.update());
    this.network.addEventListener('change', () => { this.picked = true; this.update(); });
    document.getElementById('route-clear').addEventListener('click', () => this.clear());
    this.active.addEventListener('change', () => {
      map.getCanvas().style.cursor = this.active.checked ? 'crosshair' : '';
    });
  }

  isActive() { return this.active.checked; }

  /** Route on the network under the map centre (the smallest whose bounds hold it), unless
   * the user picked one or points are placed (they belong to the network they were set on). */
  followView() {
    if (this.picked || this.markers.length) return;
    const name = this.networks.networkAt(this.map.getCenter());
    if (name) this.network.value = name;
  }

  addPoint(lngLat) {
    const el = document.createElement('div');
    el.className = 'task-point';
    const marker = new this.maplibregl.Marker({ element: el, draggable: true }).setLngLat(lngLat).addTo(this.map);
    marker.on('dragstart', () => { marker.dragged = true; });
    marker.on('dragend', () => this.update());
    el.addEventListener('click', (ev) => {
      ev.stopPropagation();
      // A drag ends with a click on the marker: that is a move, not a removal.
      if (marker.dragged) { marker.dragged = false; return; }
      this.removePoint(marker);
    });
    this.markers.push(marker);
    this.update();
  }

  removePoint(marker) {
    marker.remove();
    this.markers = this.markers.filter((m) => m !== marker);
    this.update();
  }

  clear() {
    for (const marker of this.markers) marker.remove();
    this.markers = [];
    this.picked = false;
    this.followView();
    this.update();
  }

  label(order) {
    this.markers.forEach((marker, i) => { marker.getElement().textContent = String(order[i] + 1); });
  }

  draw(geometry) {
    const features = geometry ? [{ type: 'Feature', geometry, properties: {} }] : [];
    this.map.getSource(ROUTE_SOURCE).setData({ type: 'FeatureCollection', features });
  }

  async update() {
    this.label(this.markers.map((_, i) => i));
    if (this.markers.length < 2) {
      this.draw(null);
      this.result.innerHTML = this.markers.length ? '<p>Add another point.</p>' : '';
      return;
    }
    const seq = ++this.requestSeq;
    const points = this.markers.map((m) => { const p = m.getLngLat(); return `${p.lng.toFixed(7)},${p.lat.toFixed(7)}`; }).join(';');
    const params = new URLSearchParams({ points, geometries: 'geojson', optimize: String(this.optimize.checked) });
    this.result.innerHTML = '<p>routing…</p>';
    const result = await request(`/networks/${encodeURIComponent(this.network.value)}/route?${params}`);
    if (seq !== this.requestSeq) return; // a newer request superseded this one
    if (!result.ok) {
      this.draw(null);
      this.result.innerHTML = '<p class="error route-error"></p>';
      this.result.firstChild.textContent = routeError(result);
      return;
    }
    const route = result.body.routes[0];
    this.draw(route.geometry);
    this.label(result.body.waypoints.map((w) => w.waypoint_index));
    const steps = route.legs.flatMap((leg) => leg.steps);
    this.result.innerHTML = `<p class="route-summary"><b class="distance">${formatDistance(route.distance)}</b>,
      <b class="duration">${formatDuration(route.duration)}</b></p><ol class="steps"></ol>`;
    const list = this.result.querySelector('.steps');
    for (const step of steps) {
      const li = document.createElement('li');
      li.textContent = stepText(step);
      list.appendChild(li);
    }
  }
}
