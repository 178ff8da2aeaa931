// Evaluate a 3D page payload's surface with the page's own modules (defop_editor.js, defop_solid.js) in Node.
// usage: node eval_surface.mjs input.json  ->  prints [{"X": [...], "S": [...], "embedded": bool}, ...] per Q
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

const input = JSON.parse(readFileSync(process.argv[2], "utf8"));
const mod = await import(pathToFileURL(input.js).href);
const solid = await import(new URL("defop_solid.js", pathToFileURL(input.js)).href); // beside defop_editor.js
const p = mod.decodePayload(input.meta, mod.fromBase64(input.data));
const op = mod.makeOperator(p);
const surface = solid.makeSurface(p);
const out = input.Q.map((Q) => {
  const X = op.evaluate(Q);
  return { X: Array.from(X), S: Array.from(surface.evaluate(X)), embedded: surface.embedded };
});
process.stdout.write(JSON.stringify(out));
