// Evaluate a MovableOp payload (defop.editor.movable_page.movable_to_payload) with the page's own module in Node.
// usage: node eval_movable.mjs input.json  ->  prints one entry per step: {"X": [...], "placement": [...]} after
//   {"Q": [...]} (a frame at the current placement) or {"error": message, "placement": [...]} after a refused
//   {"rest": [l, v]} (setRest), {"placement": [...]} after an accepted one.
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

const input = JSON.parse(readFileSync(process.argv[2], "utf8"));
const editor = await import(pathToFileURL(input.js).href);
const mod = await import(pathToFileURL(input.movable).href);
const p = editor.decodePayload(input.meta, editor.fromBase64(input.data));
const op = mod.makeMovable(p);
const out = input.steps.map((step) => {
  if (step.Q) return { X: Array.from(op.evaluate(step.Q)), placement: op.placement() };
  try {
    op.setRest(step.rest[0], step.rest[1]);
    return { placement: op.placement(), P: Array.from(p.P) };
  } catch (err) {
    return { error: `${err.name}: ${err.message}`, placement: op.placement(), P: Array.from(p.P) };
  }
});
process.stdout.write(JSON.stringify(out));
