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

/** The input point (0-based) a failed route names as off every road (the server's NoSegment
 * says "point N (lon,lat) ..."), or null for any other failure. */
function offRoadPoint(result) {
  if (result.body?.code !== 'NoSegment') return null;
  const found = /^point (\d+)\b/.exec(result.body.message || '');
  return found ? Number(found[1]) - 1 : null;
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
    this.profile = document.getElementById('route-profile');
    this.on = document.getElementById('route-on');
    this.result = document.getElementById('route-result');
    this.network.replaceChildren(...networks.names.map((n) => new Option(n, n)));
    this.picked = false; // the user chose the network in the list
    this.profiles = []; // the server's vehicle profiles (loadProfiles)
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
    this.network.addEventListener('change', () => this.pick(this.network.value));
    map.on('ugvmap.networkzoom', (ev) => this.pick(ev.network));
    this.profile.addEventListener('change', () => this.update());
    document.getElementById('route-clear').addEventListener('click', () => this.clear());
    this.active.addEventListener('change', () => {
      map.getCanvas().style.cursor = this.active.checked ? 'crosshair' : '';
    });
  }

  isActive() { return this.active.checked; }

  /** The vehicle profiles from the server (one list, app/routing/profiles.py): the route tool
   * names the one it routes with (a car never drives footways; a sidewalk robot may). */
  async loadProfiles() {
    const result = await request('/routing/profiles');
    this.profiles = result.ok ? result.body.profiles : [];
    if (!result.ok) {
      this.profile.replaceChildren(new Option('server default', ''));
    } else {
      this.profile.replaceChildren(...result.body.profiles.map((p) => {
        const option = new Option(p.name, p.name, false, p.name === result.body.default);
        option.title = `${p.title}; never on ${p.never.join(', ')}`;
        return option;
      }));
    }
    this.explain();
  }

  /** The user chose the network (in the list, or by zooming to it): routes stay on it. */
  pick(name) {
    this.network.value = name;
    this.picked = true;
    this.update();
  }

  /** Route on the network under the map centre (the smallest whose bounds hold it), unless
   * the user picked one or points are placed (they belong to the network they were set on). */
  followView() {
    if (!this.picked && !this.markers.length) {
      const name = this.networks.networkAt(this.map.getCenter());
      if (name) this.network.value = name;
    }
    this.explain();
  }

  /** Say which network and vehicle the route is planned for, and why that network. */
  explain() {
    if (!this.network.value) { this.on.textContent = ''; return; }
    const why = this.picked ? 'picked' : this.markers.length ? 'where the points were placed'
      : 'the network under the map centre; pick another above';
    const vehicle = this.profile.value ? ` for a ${this.profile.value}` : '';
    this.on.textContent = `Routing on ${this.network.value} (${why})${vehicle}.`;
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

  draw(geometries) {
    const features = geometries.map((geometry) => ({ type: 'Feature', geometry, properties: {} }));
    this.map.getSource(ROUTE_SOURCE).setData({ type: 'FeatureCollection', features });
  }

  /** Ask the server for a route through ``points`` ('lon,lat' texts). */
  ask(points) {
    const params = new URLSearchParams({ points: points.join(';'), geometries: 'geojson',
      optimize: String(this.optimize.checked) });
    if (this.profile.value) params.set('profile', this.profile.value);
    return request(`/networks/${encodeURIComponent(this.network.value)}/route?${params}`);
  }

  /** After a route failed because point ``bad`` (0-based) is off every road: route each run of
   * consecutive points between the points off the road, finding any further such point on
   * the way. Returns the routes that worked (with the input indices of their points), the
   * points off the road and the failures, their messages numbered as the markers are. */
  async legsThatWork(points, bad, message) {
    const off = new Map([[bad, message]]);
    const routes = [];
    const failed = [];
    const runs = (indices) => indices.reduce((acc, i) => {
      if (off.has(i)) acc.push([]); else acc[acc.length - 1].push(i);
      return acc;
    }, [[]]).filter((run) => run.length >= 2);
    const queue = runs(points.map((_, i) => i));
    while (queue.length) {
      const run = queue.shift();
      const result = await this.ask(run.map((i) => points[i]));
      if (result.ok) { routes.push({ run, body: result.body }); continue; }
      // The server numbers the run's points from 1: say them as the markers number them.
      const words = routeError(result).replace(/\bpoint (\d+)/g, (_, j) => `point ${run[j - 1] + 1}`);
      const k = offRoadPoint(result);
      if (k === null) { failed.push(words); continue; }
      off.set(run[k], words);
      queue.push(...runs(run));
    }
    return { routes, off, failed };
  }

  async update() {
    this.label(this.markers.map((_, i) => i));
    this.markers.forEach((m) => { m.getElement().classList.remove('off-road'); m.getElement().title = ''; });
    this.explain();
    if (this.markers.length < 2) {
      this.draw([]);
      this.result.innerHTML = this.markers.length ? '<p>Add another point.</p>' : '';
      return;
    }
    const seq = ++this.requestSeq;
    const points = this.markers.map((m) => { const p = m.getLngLat(); return `${p.lng.toFixed(7)},${p.lat.toFixed(7)}`; });
    this.result.innerHTML = '<p>routing…</p>';
    const result = await this.ask(points);
    if (seq !== this.requestSeq) return; // a newer request superseded this one
    if (result.ok) {
      this.label(result.body.waypoints.map((w) => w.waypoint_index));
      this.show([result.body], []);
      return;
    }
    const bad = offRoadPoint(result);
    if (bad === null) {
      this.show([], [routeError(result)]);
      return;
    }
    // One point off the road does not hide the rest: draw the legs that work, mark the point.
    const { routes, off, failed } = await this.legsThatWork(points, bad, routeError(result));
    if (seq !== this.requestSeq) return;
    for (const [i, words] of off) {
      const el = this.markers[i].getElement();
      el.classList.add('off-road');
      el.title = words;
    }
    const legs = routes.flatMap(({ run }) => run.slice(1).map((i, k) => `${run[k] + 1}→${i + 1}`));
    this.show(routes.map((r) => r.body), [...off.values(), ...failed],
      legs.length ? `Showing the legs that work: ${legs.join(', ')}.` : null);
  }

  /** Draw the routes with their total and steps, under the errors (and, for a partial route,
   * which legs are drawn). */
  show(bodies, errors, partial = null) {
    this.draw(bodies.map((b) => b.routes[0].geometry));
    const paragraph = (className, text) => {
      const p = document.createElement('p');
      p.className = className;
      p.textContent = text;
      return p;
    };
    this.result.replaceChildren(...errors.map((text) => paragraph('error route-error', text)));
    if (partial) this.result.append(paragraph('hint route-partial', partial));
    if (!bodies.length) return;
    const routes = bodies.map((b) => b.routes[0]);
    const sum = (key) => routes.reduce((total, r) => total + r[key], 0);
    const summary = document.createElement('p');
    summary.className = 'route-summary';
    summary.innerHTML = `<b class="distance">${formatDistance(sum('distance'))}</b>,
      <b class="duration">${formatDuration(sum('duration'))}</b>`;
    const list = document.createElement('ol');
    list.className = 'steps';
    for (const step of routes.flatMap((r) => r.legs.flatMap((leg) => leg.steps))) {
      const li = document.createElement('li');
      li.textContent = stepText(step);
      list.appendChild(li);
    }
    this.result.append(summary, list);
  }
}
