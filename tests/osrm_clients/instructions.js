// Reads an OSRM route response on stdin and prints, per leg, the sentence osrm-text-instructions
// makes of each step (English), as JSON: what a turn-by-turn client would say.
const compiler = require('osrm-text-instructions')('v5');

let input = '';
process.stdin.on('data', (chunk) => { input += chunk; });
process.stdin.on('end', () => {
  const legs = JSON.parse(input).routes[0].legs;
  const sentences = legs.map((leg, legIndex) => leg.steps.map(
    (step) => compiler.compile('en', step, { legCount: legs.length, legIndex })));
  process.stdout.write(JSON.stringify(sentences));
});
