// Segment side panel: attributes, edit history, and editing with a bearer token (PATCH + If-Match).
import { TOKEN_KEY, request, describeError } from './api.js';
import { FIELDS, roadClassList } from './fields.js';

const READ_ONLY = [['length_m', 'Length (m)'], ['confidence', 'Confidence'], ['version', 'Version'],
  ['updated_by', 'Updated by'], ['updated_at', 'Updated at']];

function fieldHtml(field) {
  const id = `f-${field.key}`;
  let input;
  if (field.kind === 'select') {
    input = `<select id="${id}" name="${field.key}">${field.options.map((o) => `<option>${o}</option>`).join('')}</select>`;
  } else if (field.kind === 'checkbox') {
    input = `<input type="checkbox" id="${id}" name="${field.key}">`;
  } else {
    const type = field.kind === 'text' ? 'text' : 'number';
    const step = field.kind === 'integer' ? '1' : 'any';
    const list = field.list ? ` list="${field.list}"` : '';
    input = `<input type="${type}" step="${step}" id="${id}" name="${field.key}"${list}>`;
  }
  return `<div class="field" data-field="${field.key}"><label for="${id}">${field.label}</label>${input}
    <span class="error" id="${id}-error"></span></div>`;
}

function readField(form, field) {
  const input = form.elements[field.key];
  if (field.kind === 'checkbox') return input.checked;
  if (field.kind === 'select' || field.kind === 'text') {
    return input.value === '' && field.nullable ? null : input.value;
  }
  if (input.value.trim() === '') return field.nullable ? null : '';
  return Number(input.value);
}

function writeField(form, field, value) {
  const input = form.elements[field.key];
  if (field.kind === 'checkbox') input.checked = Boolean(value);
  else input.value = value ?? '';
}

function formatValue(value, key) {
  if (value === null || value === undefined) return '—';
  if (key === 'updated_at') return new Date(value).toLocaleString();
  if (key === 'confidence') return value.toFixed(2);
  if (typeof value === 'number') return Number.isInteger(value) ? String(value) : value.toFixed(1);
  return String(value);
}

function historyItem(edit) {
  const li = document.createElement('li');
  const changes = Object.keys(edit.new || {}).filter((k) => k !== 'version')
    .map((k) => `${k}: ${formatValue(edit.old?.[k])} → ${formatValue(edit.new[k])}`);
  li.textContent = `v${edit.version_to} ${edit.action} by ${edit.edited_by}, ${new Date(edit.edited_at).toLocaleString()}`
    + (changes.length ? ` — ${changes.join('; ')}` : '');
  return li;
}

/** The side panel for one road segment at a time. `onSaved(network)` runs after each save,
 * `onDeleted(network)` after the segment was deleted, `onClose()` when the user closes it,
 * `onLayout()` after it opens or hides (the map must resize). */
export class Inspector {
  constructor({ onSaved, onDeleted, onClose, onLayout, vehicles = () => [] }) {
    this.vehicles = vehicles; // the vehicle profiles, to say which may drive the segment
    this.onSaved = onSaved;
    this.onDeleted = onDeleted;
    this.onClose = onClose;
    this.onLayout = onLayout;
    this.panel = document.getElementById('inspector');
    this.form = document.getElementById('seg-form');
    this.message = document.getElementById('seg-message');
    this.reloadButton = document.getElementById('seg-reload');
    this.token = document.getElementById('token');
    document.getElementById('seg-fields').innerHTML = FIELDS.map(fieldHtml).join('')
      + roadClassList()
      + '<dl id="seg-readonly" class="readonly"></dl>';
    this.token.value = sessionStorage.getItem(TOKEN_KEY) || '';
    this.token.addEventListener('input', () => {
      sessionStorage.setItem(TOKEN_KEY, this.token.value.trim());
      this.updateEditable();
    });
    document.getElementById('token-forget').addEventListener('click', () => {
      sessionStorage.removeItem(TOKEN_KEY);
      this.token.value = '';
      this.updateEditable();
    });
    this.form.addEventListener('submit', (ev) => { ev.preventDefault(); this.save(); });
    this.reloadButton.addEventListener('click', () => this.open(this.network, this.id));
    this.confirm = document.getElementById('seg-confirm');
    document.getElementById('seg-delete').addEventListener('click', () => { this.confirm.hidden = false; });
    document.getElementById('seg-delete-no').addEventListener('click', () => { this.confirm.hidden = true; });
    document.getElementById('seg-delete-yes').addEventListener('click', () => this.remove());
    document.getElementById('inspector-close').addEventListener('click', () => this.close());
  }

  itemUrl() {
    return `/collections/${encodeURIComponent(`${this.network}-segments`)}/items/${this.id}`;
  }

  updateEditable() {
    const editable = Boolean(this.token.value.trim()) && Boolean(this.feature);
    for (const field of FIELDS) this.form.elements[field.key].disabled = !editable;
    document.getElementById('seg-save').disabled = !editable;
    document.getElementById('seg-delete').disabled = !editable;
  }

  showMessage(text, kind) {
    this.message.textContent = text;
    this.message.className = kind || '';
  }

  clearErrors() {
    for (const span of this.form.querySelectorAll('.error')) span.textContent = '';
    for (const div of this.form.querySelectorAll('.field')) div.classList.remove('invalid');
  }

  async open(network, id) {
    this.network = network;
    this.id = id;
    this.feature = null;
    this.panel.hidden = false;
    this.onLayout();
    this.reloadButton.hidden = true;
    this.confirm.hidden = true;
    this.clearErrors();
    this.showMessage('loading…');
    document.getElementById('seg-title').textContent = `Segment ${id} (${network})`;
    const result = await request(this.itemUrl());
    if (!result.ok) {
      this.showMessage(describeError(result), 'error');
      this.updateEditable();
      return;
    }
    this.feature = result.body;
    this.etag = result.etag || `"${result.body.properties.version}"`;
    this.fill();
    this.showMessage(this.token.value.trim() ? '' : 'Paste an editor token under Access to edit.');
    this.updateEditable();
    await this.loadHistory();
  }

  fill() {
    const props = this.feature.properties;
    for (const field of FIELDS) writeField(this.form, field, props[field.key]);
    const list = document.getElementById('seg-readonly');
    list.replaceChildren();
    for (const [key, label] of READ_ONLY) {
      const dt = document.createElement('dt');
      const dd = document.createElement('dd');
      dt.textContent = label;
      dd.dataset.field = key;
      dd.textContent = formatValue(props[key], key); // server text (e.g. a token's name): never HTML
      list.append(dt, dd);
    }
    // Every way is kept (an OSM import keeps footways); which vehicle may drive this one
    // follows from its class and the profiles, said here rather than stored beside it.
    const vehicles = this.vehicles();
    if (!vehicles.length) return;
    const barred = (p) => p.never.includes(props.road_class);
    const may = vehicles.filter((p) => !barred(p)).map((p) => p.name);
    const never = vehicles.filter(barred).map((p) => p.name);
    const dt = document.createElement('dt');
    const dd = document.createElement('dd');
    dt.textContent = 'Driven by';
    dd.dataset.field = 'vehicles';
    dd.textContent = `${may.length ? may.join(', ') : 'no vehicle'}${never.length ? ` (never ${never.join(', ')})` : ''}`;
    list.append(dt, dd);
  }

  async loadHistory() {
    const list = document.getElementById('seg-history');
    const result = await request(`${this.itemUrl()}/history`);
    list.innerHTML = '';
    if (!result.ok) {
      const li = document.createElement('li');
      li.className = 'error';
      li.textContent = describeError(result);
      list.appendChild(li);
      return;
    }
    if (!result.body.edits.length) list.innerHTML = '<li class="empty">no edits yet</li>';
    for (const edit of result.body.edits.slice().reverse()) list.appendChild(historyItem(edit));
  }

  /** The merge patch: only the fields whose value differs from the loaded feature. */
  patch() {
    const props = this.feature.properties;
    const patch = {};
    for (const field of FIELDS) {
      const value = readField(this.form, field);
      if (value !== (props[field.key] ?? null)) patch[field.key] = value;
    }
    return patch;
  }

  headers() {
    return { Authorization: `Bearer ${this.token.value.trim()}`, 'If-Match': this.etag };
  }

  /** A refused write in words: a conflict offers Reload, a token problem says so. */
  refused(result, verb) {
    if (result.status === 412) {
      this.showMessage('Conflict: someone else changed this segment since you opened it. '
        + `Your changes were not ${verb}; reload to see the current values.`, 'error conflict');
      this.reloadButton.hidden = false;
    } else if (result.status === 401 || result.status === 403) {
      this.showMessage(`Not ${verb}: ${describeError(result)} (check the editor token).`, 'error');
    } else {
      this.showMessage(`Not ${verb}: ${describeError(result)}`, 'error');
    }
  }

  /** Delete the segment (its version must still be the one shown: If-Match). */
  async remove() {
    this.confirm.hidden = true;
    this.showMessage('deleting…');
    const result = await request(this.itemUrl(), { method: 'DELETE', headers: this.headers() });
    if (result.ok) {
      const { network } = this;
      this.hide();
      this.onDeleted(network);
    } else {
      this.refused(result, 'deleted');
    }
  }

  async save() {
    this.clearErrors();
    const patch = this.patch();
    if (!Object.keys(patch).length) {
      this.showMessage('Nothing changed.');
      return;
    }
    this.showMessage('saving…');
    const result = await request(this.itemUrl(), {
      method: 'PATCH',
      headers: { 'Content-Type': 'application/merge-patch+json', ...this.headers() },
      body: JSON.stringify(patch),
    });
    if (result.ok) {
      this.feature = result.body;
      this.etag = result.etag || `"${result.body.properties.version}"`;
      this.fill();
      this.showMessage(`Saved: version ${result.body.properties.version}.`, 'ok');
      this.onSaved(this.network);
      await this.loadHistory();
    } else if (result.status === 422 && result.body.errors) {
      for (const [key, problem] of Object.entries(result.body.errors)) {
        const span = document.getElementById(`f-${key}-error`);
        if (span) {
          span.textContent = problem;
          span.parentElement.classList.add('invalid');
        }
      }
      this.showMessage('Not saved: fix the highlighted fields.', 'error');
    } else {
      this.refused(result, 'saved');
    }
  }

  /** Hide the panel (another panel takes the dock, e.g. the bulk editor). */
  hide() {
    this.panel.hidden = true;
    this.feature = null;
    this.onLayout();
  }

  close() {
    this.hide();
    this.onClose();
  }
}
