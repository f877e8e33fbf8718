// Several segments selected at once, for review: shift-drag a box over the map, or
// ctrl/shift-click segments to add or remove them. Each entry keeps the version its tile
// showed: a bulk edit sends it as If-Match, so it never overwrites a change the user has not
// seen.

const CLICK_TOLERANCE_PX = 3;

/** Key of a segment across networks (segment ids are only unique within a collection URL). */
export function segmentKey(segment) { return `${segment.network}/${segment.id}`; }

/** Is this click one that adds to (or removes from) the selection rather than replacing it? */
export function isMultiClick(ev) {
  const e = ev.originalEvent || ev;
  return e.shiftKey || e.ctrlKey || e.metaKey;
}

export class Selection {
  /** `onChange(segments)` runs after every change, with the selected segments in order;
   * while `paused()` is true (the route tool has the map) shift-drag does not select. */
  constructor({ map, networks, onChange, paused }) {
    this.map = map;
    this.networks = networks;
    this.onChange = onChange;
    this.paused = paused;
    this.items = new Map();
    this.installBox();
  }

  list() { return [...this.items.values()]; }

  get size() { return this.items.size; }

  changed() {
    this.networks.highlight(this.list());
    this.onChange(this.list());
  }

  /** Replace the selection. */
  set(segments) {
    this.items = new Map(segments.map((s) => [segmentKey(s), s]));
    this.changed();
  }

  /** Add segments (a box adds to what is selected, as in desktop GIS). */
  add(segments) {
    for (const s of segments) this.items.set(segmentKey(s), s);
    this.changed();
  }

  /** Add the segment, or remove it when it is selected already (ctrl/shift-click). */
  toggle(segment) {
    const key = segmentKey(segment);
    if (this.items.has(key)) this.items.delete(key);
    else this.items.set(key, segment);
    this.changed();
  }

  /** Forget segments (deleted), without a change notice: the caller reports what happened. */
  drop(segments) {
    for (const s of segments) this.items.delete(segmentKey(s));
    this.networks.highlight(this.list());
  }

  /** Record a segment's new version (after an edit or a reload), keeping it selected. */
  update(segment) {
    const key = segmentKey(segment);
    if (this.items.has(key)) this.items.set(key, segment);
  }

  clear() {
    if (!this.items.size) return;
    this.items.clear();
    this.changed();
  }

  /** Shift-drag draws a box and selects the segments it meets. MapLibre's own shift-drag
   * (zoom to a box) is turned off, and map panning is held while the box is drawn. */
  installBox() {
    const map = this.map;
    map.boxZoom.disable();
    const canvas = map.getCanvasContainer();
    let start = null;
    let box = null;
    const at = (ev) => {
      const rect = canvas.getBoundingClientRect();
      return { x: ev.clientX - rect.left - canvas.clientLeft, y: ev.clientY - rect.top - canvas.clientTop };
    };
    const move = (ev) => {
      const now = at(ev);
      // A shift-click that wobbles a pixel is a click (MapLibre's tolerance), not a box.
      if (!box && Math.hypot(now.x - start.x, now.y - start.y) < CLICK_TOLERANCE_PX) return;
      if (!box) {
        box = document.createElement('div');
        box.className = 'select-box';
        canvas.appendChild(box);
      }
      box.style.left = `${Math.min(start.x, now.x)}px`;
      box.style.top = `${Math.min(start.y, now.y)}px`;
      box.style.width = `${Math.abs(now.x - start.x)}px`;
      box.style.height = `${Math.abs(now.y - start.y)}px`;
    };
    const up = (ev) => {
      document.removeEventListener('mousemove', move);
      document.removeEventListener('mouseup', up);
      map.dragPan.enable();
      const end = at(ev);
      if (box) {
        box.remove();
        box = null;
        const found = this.networks.segmentsIn([[Math.min(start.x, end.x), Math.min(start.y, end.y)],
          [Math.max(start.x, end.x), Math.max(start.y, end.y)]]);
        if (found.length) this.add(found);
      }
      start = null;
    };
    // Capture phase: the box must start before MapLibre's own handlers see the mouse press.
    canvas.addEventListener('mousedown', (ev) => {
      if (!ev.shiftKey || ev.button !== 0 || this.paused()) return;
      map.dragPan.disable();
      start = at(ev);
      document.addEventListener('mousemove', move);
      document.addEventListener('mouseup', up);
    }, true);
  }
}
