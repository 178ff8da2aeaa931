// Evaluate a defop payload with the page's own module (defop/static/defop_editor.js) in Node.
// usage: node eval_operator.mjs input.json  ->  prints {"X": [...], "psi": [...], "outside": [...]} per Q
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

const input = JSON.parse(readFileSync(process.argv[2], "utf8"));
const mod = await import(pathToFileURL(input.js).href);
const p = mod.decodePayload(input.meta, mod.fromBase64(input.data));
const op = mod.makeOperator(p);
const out = input.Q.map((Q) => ({
  X: Array.from(op.evaluate(Q)),
  psi: Array.from(op.psi(Q)),
  outside: mod.extrapolating(Q, p),
}));
process.stdout.write(JSON.stringify(out));
