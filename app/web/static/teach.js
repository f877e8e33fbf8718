// Teach tool: labels drawn on a raster layer (road lines, "not road" boxes) through
// /layers/{slug}/labels, a preview of the view re-extracted with them (a job the server's
// workers run), drawn dashed magenta over the networks, and Accept into a network.
import { request, describeError, editorHeaders } from './api.js';

const DRAFT = 'teach-draft';
const LABELS = 'teach-labels';
const PREVIEW = 'teach-preview';
const POLL_MS = 400;
const EMPTY = { type: 'FeatureCollection', features: [] };

/** Lon/lat box of two corners, as a closed polygon ring. */
function boxPolygon([x0, y0], [x1, y1]) {
  const [w, e, s, n] = [Math.min(x0, x1), Math.max(x0, x1), Math.min(y0, y1), Math.max(y0, y1)];
  return { type: 'Polygon', coordinates: [[[w, s], [e, s], [e, n], [w, n], [w, s]]] };
}

/** Describe a finished preview: how many roads, how sure, from what sample, how fast. */
export function previewSummary(result) {
  const roads = result.features.length;
  const conf = result.features.map((f) => f.properties.confidence).filter((c) => c != null);
  const mean = conf.length ? (conf.reduce((a, b) => a + b, 0) / conf.length).toFixed(2) : '–';
  const { road = 0, not_road: notRoad = 0 } = result.labels || {};
  const sample = road + notRoad ? `${road} road / ${notRoad} not-road labels` : 'no labels (zero-shot)';
  const used = result.sample ? ` (${result.sample})` : '';
  return `${roads} roads, confidence mean ${mean}; ${sample}${used}, ${result.seconds} s`;
}

export class TeachTool {
  /** ``onAccepted(network)`` redraws the network that took the preview's roads. */
  constructor({ map, layers, networks, onAccepted }) {
    this.map = map;
    this.onAccepted = onAccepted;
    this.active = document.getElementById('teach-active');
    this.layer = document.getElementById('teach-layer');
    this.network = document.getElementById('teach-network');
    this.list = document.getElementById('teach-labels');
    this.result = document.getElementById('teach-result');
    this.previewButton = document.getElementById('teach-preview');
    this.acceptButton = document.getElementById('teach-accept');
    this.layer.replaceChildren(...layers.map((slug) => new Option(slug, slug)));
    this.network.replaceChildren(...networks.names.map((n) => new Option(n, n)));
    this.draft = []; // vertices of the stroke being drawn
    this.previewId = null;
    this.pollSeq = 0;
    for (const [id, data] of [[DRAFT, EMPTY], [LABELS, EMPTY], [PREVIEW, EMPTY]]) {
      map.addSource(id, { type: 'geojson', data });
    }
    map.addLayer({ id: 'teach-not-road-area', type: 'fill', source: LABELS,
      filter: ['==', ['geometry-type'], 'Polygon'],
      paint: { 'fill-color': '#d62728', 'fill-opacity': 0.25, 'fill-outline-color': '#d62728' } });
    map.addLayer({ id: 'teach-label-line', type: 'line', source: LABELS,
      filter: ['==', ['geometry-type'], 'LineString'],
      paint: { 'line-width': 4,
        'line-color': ['match', ['get', 'label'], 'road', '#2ca02c', '#d62728'] } });
    map.addLayer({ id: 'teach-draft-line', type: 'line', source: DRAFT,
      paint: { 'line-color': '#ff7f0e', 'line-width': 3, 'line-dasharray': [1, 1] } });
    map.addLayer({ id: 'teach-preview-line', type: 'line', source: PREVIEW,
      layout: { 'line-cap': 'butt' },
      paint: { 'line-color': '#ff00ff', 'line-width': 4, 'line-dasharray': [2, 1.5] } });
    this.active.addEventListener('change', () => this.toggle());
    this.layer.addEventListener('change', () => this.loadLabels());
    this.previewButton.addEventListener('click', () => this.preview());
    this.acceptButton.addEventListener('click', () => this.accept());
    map.on('dblclick', (ev) => {
      if (!this.isActive()) return;
      ev.preventDefault(); // a double click ends the stroke, it does not zoom
      this.finishStroke();
    });
  }

  isActive() { return this.active.checked; }

  mode() { return document.querySelector('input[name="teach-mode"]:checked').value; }

  toggle() {
    this.map.getCanvas().style.cursor = this.isActive() ? 'crosshair' : '';
    this.draft = [];
    this.drawDraft();
    if (this.isActive()) this.loadLabels();
  }

  /** A click while teaching: a vertex of the road / not-road line, or a corner of a box. */
  click(lngLat) {
    this.draft.push([lngLat.lng, lngLat.lat]);
    if (this.mode() === 'not_road_box' && this.draft.length === 2) {
      const [a, b] = this.draft;
      this.draft = [];
      this.save({ type: 'Feature', geometry: boxPolygon(a, b), properties: { label: 'not_road' } });
    }
    this.drawDraft();
  }

  finishStroke() {
    // The double click's two clicks each added a vertex at the same spot: keep one.
    const points = this.draft.filter((p, i, all) => i === 0 || p[0] !== all[i - 1][0] || p[1] !== all[i - 1][1]);
    this.draft = [];
    this.drawDraft();
    if (this.mode() === 'not_road_box' || points.length < 2) return;
    const label = this.mode() === 'road' ? 'road' : 'not_road';
    this.save({ type: 'Feature', geometry: { type: 'LineString', coordinates: points }, properties: { label } });
  }

  drawDraft() {
    const features = this.draft.length > 1
      ? [{ type: 'Feature', geometry: { type: 'LineString', coordinates: this.draft }, properties: {} }] : [];
    this.map.getSource(DRAFT).setData({ type: 'FeatureCollection', features });
  }

  labelsUrl() { return `/layers/${encodeURIComponent(this.layer.value)}/labels`; }

  async save(feature) {
    const result = await request(this.labelsUrl(), {
      method: 'POST', headers: editorHeaders(), body: JSON.stringify(feature) });
    if (!result.ok) this.say(`Label not saved: ${describeError(result)}`);
    await this.loadLabels();
  }

  async loadLabels() {
    if (!this.layer.value) return;
    const result = await request(this.labelsUrl());
    if (!result.ok) {
      this.say(`Labels: ${describeError(result)}`);
      return;
    }
    this.map.getSource(LABELS).setData(result.body);
    this.list.replaceChildren(...result.body.features.map((f) => this.labelEntry(f)));
  }

  labelEntry(feature) {
    const li = document.createElement('li');
    li.dataset.label = feature.id;
    const kind = feature.geometry.type === 'Polygon' ? 'not-road area' : `${feature.properties.label.replace('_', '-')} line`;
    li.textContent = `${kind} #${feature.id} `;
    const remove = document.createElement('button');
    remove.type = 'button';
    remove.className = 'remove';
    remove.textContent = 'Remove';
    remove.addEventListener('click', async () => {
      const result = await request(`${this.labelsUrl()}/${feature.id}`, {
        method: 'DELETE', headers: editorHeaders() });
      if (!result.ok && result.status !== 204) this.say(`Not removed: ${describeError(result)}`);
      await this.loadLabels();
    });
    li.append(remove);
    return li;
  }

  say(text) { this.result.textContent = text; }

  /** Ask for a preview of the current view, then follow it until it is done. */
  async preview() {
    const b = this.map.getBounds();
    const bbox = [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()];
    this.previewId = null;
    this.acceptButton.disabled = true;
    this.map.getSource(PREVIEW).setData(EMPTY);
    this.say('Preview queued…');
    const asked = await request(`/layers/${encodeURIComponent(this.layer.value)}/previews`, {
      method: 'POST', headers: editorHeaders(), body: JSON.stringify({ bbox }) });
    if (!asked.ok) {
      this.say(`No preview: ${describeError(asked)}`);
      return;
    }
    const seq = ++this.pollSeq;
    const url = `/layers/${encodeURIComponent(this.layer.value)}/previews/${asked.body.id}`;
    for (;;) {
      const state = await request(url);
      if (seq !== this.pollSeq) return; // a newer preview replaced this one
      if (!state.ok) {
        this.say(`Preview: ${describeError(state)}`);
        return;
      }
      const { status, progress, message, error, result } = state.body;
      if (status === 'failed') {
        this.say(`Preview failed: ${error}`);
        return;
      }
      if (status === 'succeeded') {
        this.map.getSource(PREVIEW).setData(result);
        this.previewId = asked.body.id;
        this.acceptButton.disabled = false;
        this.say(`Preview: ${previewSummary(result)}`);
        return;
      }
      this.say(`Preview ${status}, ${Math.round(progress * 100)} %${message ? `: ${message}` : ''}`);
      await new Promise((resolve) => { setTimeout(resolve, POLL_MS); });
    }
  }

  /** Put the shown preview's roads into the chosen network. */
  async accept() {
    if (this.previewId == null) return;
    const network = this.network.value;
    const answer = await request(
      `/layers/${encodeURIComponent(this.layer.value)}/previews/${this.previewId}/accept`,
      { method: 'POST', headers: editorHeaders(), body: JSON.stringify({ network }) });
    if (!answer.ok) {
      this.say(`Not accepted: ${describeError(answer)}`);
      return;
    }
    const { added, moved, removed, kept, left, change_set: changeSet } = answer.body;
    this.say(`Accepted into ${network} as change set ${changeSet}: ${added} added, ${moved} `
      + `moved, ${removed} removed, ${kept} kept`
      + (left ? `; ${left} left for Review changes` : ''));
    this.previewId = null;
    this.acceptButton.disabled = true;
    this.map.getSource(PREVIEW).setData(EMPTY);
    this.onAccepted(network);
  }
}
