// Runs Leaflet Routing Machine's own OSRM v1 router (src/osrm-v1.js, unmodified) in a jsdom
// page served from the same origin as the server, twice (the second request sends back the
// hints of the first, as LRM does), and prints the URLs it requested and the routes it parsed.
// Usage: node lrm.js SERVICE_URL '[[lat, lng], ...]'
const { JSDOM } = require('jsdom');

const [serviceUrl, latLngs] = [process.argv[2], JSON.parse(process.argv[3])];
const dom = new JSDOM('<!doctype html><html><body></body></html>', { url: new URL(serviceUrl).origin + '/' });
Object.assign(global, { window: dom.window, document: dom.window.document,
  navigator: dom.window.navigator, location: dom.window.location });
const L = require('leaflet');
const OSRMv1 = require('leaflet-routing-machine/src/osrm-v1');

const router = new OSRMv1({ serviceUrl, profile: 'driving' });
const waypoints = latLngs.map(([lat, lng]) => ({ latLng: L.latLng(lat, lng), name: '', options: {} }));

function once() {
  const url = router.buildRouteUrl(waypoints, L.extend({}, router.options.routingOptions));
  return new Promise((resolve) => {
    router.route(waypoints, (err, routes) => {
      resolve({ url, err: err || null, routes: (routes || []).map((r) => ({
        name: r.name, summary: r.summary, coordinates: r.coordinates.length,
        first: [r.coordinates[0].lat, r.coordinates[0].lng], waypointIndices: r.waypointIndices,
        waypoints: r.waypoints.map((w) => [w.latLng.lat, w.latLng.lng]),
        instructions: r.instructions.map((i) => ({ type: i.type, text: i.text, road: i.road,
          distance: i.distance, index: i.index, direction: i.direction })),
      })) });
    });
  });
}

(async () => {
  const first = await once();
  const second = await once();
  process.stdout.write(JSON.stringify([first, second]));
  process.exit(0);
})();
