// Review tool: the change sets re-surveys proposed for a network (/networks/{name}/changes),
// one drawn over the imagery in its own style (moved: orange dashes, new: cyan, missing: red
// dots; decided ones faded), and accept / reject one by one (click a proposal), in the view,
// by kind or all, and revert a whole set (/change-sets/{id}/...).
import { request, describeError, editorHeaders } from './api.js';

const SOURCE = 'review-changes';
const EMPTY = { type: 'FeatureCollection', features: [] };
const COLOURS = ['match', ['get', 'kind'], 'moved', '#ff9f1c', 'new', '#00d5ff', '#ff3b30'];
export const REVIEW_LAYERS = ['review-missing', 'review-moved-new'];

/** One line on a change set for its list: id, source and what is still to decide. */
export function setLabel(set) {
  const open = Object.entries(set.proposals).filter(([k]) => k.endsWith(':proposed'))
    .map(([k, n]) => `${n} ${k.split(':')[0]}`).join(', ');
  return `#${set.id} ${set.source} (${set.status}${open ? `; to review: ${open}` : ''})`;
}

export class ReviewTool {
  /** ``onChanged(network)`` redraws a network a decision changed. */
  constructor({ map, networks, onChanged }) {
    this.map = map;
    this.onChanged = onChanged;
    this.active = document.getElementById('review-active');
    this.network = document.getElementById('review-network');
    this.set = document.getElementById('review-set');
    this.kind = document.getElementById('review-kind');
    this.result = document.getElementById('review-result');
    this.picked = document.getElementById('review-picked');
    this.chosen = null; // the clicked proposal
    this.network.replaceChildren(...networks.names.map((n) => new Option(n, n)));
    map.addSource(SOURCE, { type: 'geojson', data: EMPTY });
    const faded = ['case', ['==', ['get', 'status'], 'proposed'], 0.95, 0.3];
    map.addLayer({ id: 'review-missing', type: 'line', source: SOURCE,
      filter: ['==', ['get', 'kind'], 'missing'], layout: { 'line-cap': 'round' },
      paint: { 'line-color': COLOURS, 'line-width': 5, 'line-opacity': faded, 'line-dasharray': [0.2, 2] } });
    map.addLayer({ id: 'review-moved-new', type: 'line', source: SOURCE,
      filter: ['!=', ['get', 'kind'], 'missing'],
      paint: { 'line-color': COLOURS, 'line-width': ['match', ['get', 'kind'], 'new', 5, 4],
        'line-opacity': faded, 'line-dasharray': [2, 1] } });
    this.active.addEventListener('change', () => this.toggle());
    this.network.addEventListener('change', () => this.loadSets());
    this.set.addEventListener('change', () => this.show());
    const decide = (id, verb, body) => document.getElementById(id)
      .addEventListener('click', () => this.decide(verb, body()));
    decide('review-accept-picked', 'accept', () => ({ changes: [this.chosen] }));
    decide('review-reject-picked', 'reject', () => ({ changes: [this.chosen] }));
    decide('review-accept-kind', 'accept', () => ({ kind: this.kind.value }));
    decide('review-accept-view', 'accept', () => ({ bbox: this.view() }));
    decide('review-reject-view', 'reject', () => ({ bbox: this.view() }));
    decide('review-accept-all', 'accept', () => ({ all: true }));
    document.getElementById('review-revert').addEventListener('click', () => this.revert());
  }

  isActive() { return this.active.checked; }

  view() {
    const b = this.map.getBounds();
    return [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()];
  }

  say(text) { this.result.textContent = text; }

  toggle() {
    if (this.isActive()) this.loadSets();
    else this.map.getSource(SOURCE).setData(EMPTY);
  }

  async loadSets() {
    const keep = this.set.value;
    const answer = await request(`/networks/${encodeURIComponent(this.network.value)}/changes`);
    if (!answer.ok) {
      this.say(`Change sets: ${describeError(answer)}`);
      return;
    }
    this.set.replaceChildren(...answer.body.map((s) => new Option(setLabel(s), s.id)).reverse());
    if (!answer.body.length) this.say('No change sets: update the network with `--update`.');
    if (keep && answer.body.some((s) => String(s.id) === keep)) this.set.value = keep;
    await this.show();
  }

  /** Draw the chosen change set's proposals. */
  async show() {
    this.pick(null);
    if (!this.set.value) {
      this.map.getSource(SOURCE).setData(EMPTY);
      return;
    }
    const answer = await request(`/change-sets/${this.set.value}`);
    if (!answer.ok) {
      this.say(`Change set: ${describeError(answer)}`);
      return;
    }
    this.map.getSource(SOURCE).setData(answer.body);
    const open = answer.body.features.filter((f) => f.properties.status === 'proposed');
    const edited = open.filter((f) => f.properties.edited).length;
    this.say(`${open.length} proposals to review${edited ? `, ${edited} on roads a person edited (accept those one by one)` : ''}`);
  }

  /** A click on the map while reviewing: the proposal under it, if any. */
  click(point) {
    const hit = this.map.queryRenderedFeatures(point, { layers: REVIEW_LAYERS })
      .find((f) => f.properties.status === 'proposed');
    this.pick(hit || null);
  }

  pick(feature) {
    this.chosen = feature ? feature.id : null;
    const p = feature && feature.properties;
    this.picked.textContent = p ? `Change #${feature.id}: ${p.kind} ${p.segment_id && p.segment_id !== 'null' ? `segment ${p.segment_id}` : 'road'}`
      + (p.edited === true || p.edited === 'true' ? ' (edited by a person)' : '') : 'Click a proposal to pick it.';
    for (const id of ['review-accept-picked', 'review-reject-picked']) {
      document.getElementById(id).disabled = this.chosen == null;
    }
  }

  async decide(verb, body) {
    if (!this.set.value) return;
    const answer = await request(`/change-sets/${this.set.value}/${verb}`, {
      method: 'POST', headers: editorHeaders(), body: JSON.stringify(body) });
    if (!answer.ok) {
      this.say(`Not ${verb}ed: ${describeError(answer)}`);
      return;
    }
    const counts = Object.entries(answer.body).map(([k, n]) => `${n} ${k}`).join(', ');
    await this.loadSets();
    this.say(`${verb === 'accept' ? 'Accepted' : 'Rejected'}: ${counts}`);
    if (verb === 'accept') this.onChanged(this.network.value);
  }

  async revert() {
    if (!this.set.value) return;
    const answer = await request(`/change-sets/${this.set.value}/revert`, {
      method: 'POST', headers: editorHeaders() });
    if (!answer.ok) {
      this.say(`Not reverted: ${describeError(answer)}`);
      return;
    }
    await this.loadSets();
    this.say(`Reverted: ${answer.body.reverted} changes undone`);
    this.onChanged(this.network.value);
  }
}
