// Bulk review of the selected segments: set attributes on all of them, or delete them, in one
// action. Each segment is still its own request with its own If-Match (the version its tile
// showed), so each gets its own history entry and version check: a segment someone else
// changed meanwhile is refused (412) and named, the others stay applied.
import { request, describeError, savedToken } from './api.js';
import { FIELDS, roadClassList } from './fields.js';

const IN_FLIGHT = 4; // requests at once: fast enough for hundreds, gentle on the server
const NEEDS_TOKEN = 'Paste an editor token under Access to edit or delete.';

function itemUrl(segment) {
  return `/collections/${encodeURIComponent(`${segment.network}-segments`)}/items/${segment.id}`;
}

/** An input that means "leave unchanged" when empty (selects: their first option). */
function bulkFieldHtml(field) {
  const id = `b-${field.key}`;
  let input;
  if (field.kind === 'select' || field.kind === 'checkbox') {
    const options = field.kind === 'select' ? field.options : ['true', 'false'];
    const label = (o) => (field.kind === 'checkbox' ? { true: 'yes', false: 'no' }[o] : o);
    input = `<select id="${id}" name="${field.key}"><option value="">unchanged</option>${
      options.map((o) => `<option value="${o}">${label(o)}</option>`).join('')}</select>`;
  } else {
    const type = field.kind === 'text' ? 'text' : 'number';
    const step = field.kind === 'integer' ? '1' : 'any';
    const list = field.list ? ` list="${field.list}"` : '';
    input = `<input type="${type}" step="${step}" id="${id}" name="${field.key}" placeholder="unchanged"${list}>`;
  }
  return `<div class="field"><label for="${id}">${field.label}</label>${input}</div>`;
}

function readBulkField(form, field) {
  const raw = form.elements[field.key].value;
  if (raw.trim() === '') return undefined;
  if (field.kind === 'checkbox') return raw === 'true';
  if (field.kind === 'integer' || field.kind === 'number') return Number(raw);
  return raw;
}

/** Run `work` on every item with at most `limit` at once; results in the items' order. */
async function inPool(items, limit, work) {
  const results = new Array(items.length);
  let next = 0;
  const worker = async () => {
    while (next < items.length) {
      const i = next++;
      results[i] = await work(items[i]);
    }
  };
  await Promise.all(Array.from({ length: Math.min(limit, items.length) }, worker));
  return results;
}

function idList(segments) {
  return segments.map((s) => s.id).join(', ');
}

/** The panel for a selection of segments. `onChanged(networks)` runs after an action changed
 * segments of those networks; `onClose()` when the user closes the panel; `onLayout()` after
 * it opens or hides. */
export class BulkEditor {
  constructor({ selection, onChanged, onClose, onLayout }) {
    this.selection = selection;
    this.onChanged = onChanged;
    this.onClose = onClose;
    this.onLayout = onLayout;
    this.panel = document.getElementById('bulk');
    this.form = document.getElementById('bulk-form');
    this.message = document.getElementById('bulk-message');
    this.reloadButton = document.getElementById('bulk-reload');
    this.confirm = document.getElementById('bulk-confirm');
    this.conflicts = [];
    document.getElementById('bulk-fields').innerHTML = FIELDS.map(bulkFieldHtml).join('') + roadClassList();
    this.form.addEventListener('submit', (ev) => { ev.preventDefault(); this.apply(); });
    document.getElementById('bulk-delete').addEventListener('click', () => this.askDelete());
    document.getElementById('bulk-delete-yes').addEventListener('click', () => this.remove());
    document.getElementById('bulk-delete-no').addEventListener('click', () => { this.confirm.hidden = true; });
    this.reloadButton.addEventListener('click', () => this.reload());
    document.getElementById('bulk-close').addEventListener('click', () => this.close());
    // A token pasted (or forgotten) while the panel is open enables (or disables) its buttons.
    const retoken = () => { if (!this.panel.hidden) this.show(this.selection.list(), true); };
    document.getElementById('token').addEventListener('input', retoken);
    document.getElementById('token-forget').addEventListener('click', retoken);
  }

  get busy() { return this.form.classList.contains('busy'); }

  /** Show the panel for the selection: on a new selection the last action's report goes;
   * after an action (`report`) it stays. */
  show(segments, report = false) {
    if (!segments.length) {
      this.hide();
      return;
    }
    if (!report) {
      this.showMessage('');
      this.reloadButton.hidden = true;
      this.conflicts = [];
    }
    const networks = new Set(segments.map((s) => s.network));
    document.getElementById('bulk-title').textContent = `${segments.length} segment${segments.length === 1 ? '' : 's'} selected`
      + (networks.size > 1 ? ` in ${networks.size} networks` : ` (${[...networks][0]})`);
    const list = document.getElementById('bulk-list');
    list.replaceChildren(...[...segments].sort((a, b) => a.id - b.id).map((s) => {
      const li = document.createElement('li');
      li.dataset.segment = String(s.id);
      li.textContent = `${s.id} (v${s.version})`;
      return li;
    }));
    this.confirm.hidden = true;
    const editable = Boolean(savedToken());
    for (const button of this.form.querySelectorAll('button')) button.disabled = !editable || this.busy;
    if (!editable) this.showMessage(NEEDS_TOKEN);
    else if (this.message.textContent === NEEDS_TOKEN) this.showMessage('');
    if (this.panel.hidden) {
      this.panel.hidden = false;
      this.onLayout();
    }
  }

  hide() {
    if (this.panel.hidden) return;
    this.panel.hidden = true;
    this.onLayout();
  }

  close() {
    this.hide();
    this.onClose();
  }

  showMessage(text, kind) {
    this.message.textContent = text;
    this.message.className = kind || '';
  }

  /** The attributes to set: every field not left "unchanged". */
  patch() {
    const patch = {};
    for (const field of FIELDS) {
      const value = readBulkField(this.form, field);
      if (value !== undefined) patch[field.key] = value;
    }
    return patch;
  }

  /** One request per segment with its own If-Match; the answers sorted into what happened. */
  async send(method, segments, body) {
    this.form.classList.add('busy');
    this.show(segments, true);
    const headers = { Authorization: `Bearer ${savedToken()}` };
    if (body) headers['Content-Type'] = 'application/merge-patch+json';
    const results = await inPool(segments, IN_FLIGHT, (s) => request(itemUrl(s), {
      method, headers: { ...headers, 'If-Match': `"${s.version}"` }, body: body && JSON.stringify(body),
    }));
    this.form.classList.remove('busy');
    const outcome = { done: [], conflicts: [], failed: [] };
    results.forEach((result, i) => {
      const segment = segments[i];
      if (result.ok || (method === 'DELETE' && result.status === 404)) {
        outcome.done.push(result.ok && result.body?.properties
          ? { ...segment, version: result.body.properties.version } : segment);
      } else if (result.status === 412) {
        outcome.conflicts.push(segment);
      } else {
        const fields = result.body?.errors;
        const why = fields ? Object.entries(fields).map(([k, v]) => `${k} ${v}`).join('; ') : describeError(result);
        outcome.failed.push([segment, why]);
      }
    });
    this.conflicts = outcome.conflicts;
    this.report(method === 'DELETE' ? 'Deleted' : 'Saved', segments.length, outcome);
    this.onChanged(new Set(segments.map((s) => s.network)));
    return outcome;
  }

  report(verb, total, { done, conflicts, failed }) {
    const lines = [`${verb} ${done.length} of ${total} segment${total === 1 ? '' : 's'}.`];
    if (conflicts.length) {
      lines.push(`Not ${verb.toLowerCase()}: segment${conflicts.length === 1 ? '' : 's'} ${idList(conflicts)} `
        + `changed since you selected ${conflicts.length === 1 ? 'it' : 'them'} (someone else edited `
        + `${conflicts.length === 1 ? 'it' : 'them'}). Reload to see the current values, then apply again.`);
    }
    for (const [segment, why] of failed) lines.push(`Segment ${segment.id}: ${why}`);
    const trouble = conflicts.length || failed.length;
    this.showMessage(lines.join(' '), trouble ? 'error' : 'ok');
    this.reloadButton.hidden = !conflicts.length;
  }

  async apply() {
    const patch = this.patch();
    if (!Object.keys(patch).length) {
      this.showMessage('Choose at least one attribute to set.', 'error');
      return;
    }
    this.showMessage('saving…');
    const outcome = await this.send('PATCH', this.selection.list(), patch);
    for (const segment of outcome.done) this.selection.update(segment);
    this.show(this.selection.list(), true);
    this.mark(outcome);
  }

  /** Mark each listed segment with what happened to it. */
  mark({ conflicts, failed }) {
    const marks = new Map([...conflicts.map((s) => [s.id, 'conflict']), ...failed.map(([s]) => [s.id, 'error'])]);
    for (const li of document.querySelectorAll('#bulk-list li')) {
      li.className = marks.get(Number(li.dataset.segment)) || 'ok';
    }
  }

  askDelete() {
    const n = this.selection.size;
    this.confirm.querySelector('span').textContent = `Delete ${n} segment${n === 1 ? '' : 's'} for good?`;
    this.confirm.hidden = false;
  }

  async remove() {
    this.confirm.hidden = true;
    this.showMessage('deleting…');
    const outcome = await this.send('DELETE', this.selection.list());
    this.selection.drop(outcome.done);
    if (this.selection.size) {
      this.show(this.selection.list(), true);
      this.mark(outcome);
    } else {
      document.getElementById('bulk-list').replaceChildren();
      document.getElementById('bulk-title').textContent = 'Nothing selected';
    }
  }

  /** Read the current version of every segment that was changed meanwhile, so the next
   * action is checked against what the user now sees. */
  async reload() {
    const results = await inPool(this.conflicts, IN_FLIGHT, (s) => request(itemUrl(s)));
    const gone = [];
    results.forEach((result, i) => {
      const segment = this.conflicts[i];
      if (result.ok) this.selection.update({ ...segment, version: result.body.properties.version });
      else gone.push(segment);
    });
    this.selection.drop(gone);
    const reloaded = this.conflicts.filter((s) => !gone.includes(s));
    this.onChanged(new Set(this.conflicts.map((s) => s.network)));
    this.conflicts = [];
    this.reloadButton.hidden = true;
    this.show(this.selection.list(), true);
    this.showMessage(`Reloaded segment${reloaded.length === 1 ? '' : 's'} ${idList(reloaded)} at the current version.`
      + (gone.length ? ` Segments ${idList(gone)} no longer exist.` : '')
      + ' Apply again to change them.', 'ok');
  }
}
