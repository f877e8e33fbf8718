// The editable segment attributes, shared by the one-segment inspector and the bulk editor so
// both offer the same fields with the same inputs.

// In display order; `kind` picks the input and how its value is read back.
export const FIELDS = [
  { key: 'name', label: 'Name', kind: 'text', nullable: true },
  { key: 'road_class', label: 'Road class', kind: 'text', list: 'road-classes' },
  { key: 'speed_limit_kph', label: 'Speed limit (km/h)', kind: 'number', nullable: true },
  { key: 'lanes_forward', label: 'Lanes forward', kind: 'integer' },
  { key: 'lanes_backward', label: 'Lanes backward', kind: 'integer' },
  { key: 'oneway', label: 'One-way', kind: 'select', options: ['none', 'forward', 'backward'] },
  { key: 'is_junction', label: 'Junction', kind: 'checkbox' },
  { key: 'surface', label: 'Surface', kind: 'text', nullable: true },
  { key: 'width_m', label: 'Width (m)', kind: 'number', nullable: true },
];

export const ROAD_CLASSES = ['motorway', 'trunk', 'primary', 'secondary', 'tertiary', 'unclassified',
  'residential', 'living_street', 'service', 'track', 'road', 'path'];

/** The <datalist> of road classes a text input offers (``list="road-classes"``). */
export function roadClassList() {
  return `<datalist id="road-classes">${ROAD_CLASSES.map((c) => `<option value="${c}">`).join('')}</datalist>`;
}
