// Lane boundary popup: what a painted line clicked beside its road is, and, with an editor
// token, its kind and colour changed in place (PATCH with the If-Match of the version shown).
import { describeError, editorHeaders, request } from './api.js';

const choices = new Map();

/** The kinds and colours a boundary may take, as the collection's JSON Schema lists them (the
 * server's own enums: a copy here would fall behind them when a kind is added); read once per
 * collection, and again after a failed read. */
function choicesOf(collection) {
  if (!choices.has(collection)) {
    choices.set(collection, request(`${collection}/schema`).then((answer) => {
      if (!answer.ok) choices.delete(collection);
      const props = (answer.ok && answer.body.properties) || {};
      return { kind: props.kind?.enum, colour: props.colour?.enum };
    }));
  }
  return choices.get(collection);
}

function select(name, options, value) {
  const el = document.createElement('select');
  el.name = name;
  el.replaceChildren(...options.map((o) => new Option(o, o, false, o === value)));
  return el;
}

export class LanePopup {
  /** ``saved(network)`` is told after an edit, so the network's tiles are drawn again. */
  constructor(map, maplibregl, saved) {
    this.map = map;
    this.saved = saved;
    this.popup = new maplibregl.Popup({ closeButton: true, maxWidth: '300px' });
  }

  remove() {
    this.popup.remove();
  }

  /** The boundary ``lane`` ({network, id, properties} of its tile feature) at ``lngLat``:
   * its feature is read first, so the form shows (and the save names) its current version. */
  async show(lane, lngLat) {
    if (!lane) { this.remove(); return; }
    const collection = `/collections/${encodeURIComponent(`${lane.network}-lanes`)}`;
    const url = `${collection}/items/${lane.id}`;
    const [current, allowed] = await Promise.all([request(url), choicesOf(collection)]);
    const p = current.ok ? current.body.properties : lane.properties;
    const box = document.createElement('div');
    box.className = 'lane-info';
    box.innerHTML = `<strong>Lane boundary ${lane.id}</strong><dl></dl>`
      + '<form class="lane-edit"><label>kind </label><label>colour </label>'
      + '<button type="submit">Save</button><span class="lane-said"></span></form>'
      + '<a target="_blank">feature (OGC API)</a>';
    const rows = [['from', p.source === 'paint' ? 'the paint' : 'an offset (no paint)'],
      ['position', p.position ?? '–'], ['segment', p.segment_id], ['confidence', p.confidence ?? '–'],
      ['version', p.version ?? '–']];
    box.querySelector('dl').replaceChildren(...rows.flatMap(([k, v]) => {
      const dt = document.createElement('dt'); dt.textContent = k;
      const dd = document.createElement('dd'); dd.textContent = String(v);
      return [dt, dd];
    }));
    const [kindLabel, colourLabel] = box.querySelectorAll('label');
    kindLabel.append(select('kind', allowed.kind ?? [p.kind], p.kind));
    colourLabel.append(select('colour', allowed.colour ?? [p.colour], p.colour));
    const form = box.querySelector('form');
    const said = box.querySelector('.lane-said');
    if (!current.ok) said.textContent = ` ${describeError(current)}`;
    form.addEventListener('submit', (ev) => {
      ev.preventDefault();
      this.save(url, lane.network, current.etag, { kind: form.kind.value, colour: form.colour.value }, said);
    });
    box.querySelector('a').href = url;
    this.popup.setLngLat(lngLat).setDOMContent(box).addTo(this.map);
  }

  async save(url, network, etag, change, said) {
    const headers = { ...editorHeaders(), ...(etag ? { 'If-Match': etag } : {}) };
    const answer = await request(url, { method: 'PATCH', headers, body: JSON.stringify(change) });
    if (!answer.ok) {
      said.textContent = ` Not saved: ${describeError(answer)}`;
      return;
    }
    said.textContent = ` Saved (version ${answer.body.properties.version})`;
    this.saved(network);
  }
}
