// Decode a (compact) page payload with the page's own module and evaluate it in Node.
// usage: node decode_payload.mjs input.json  ->  prints {"B": [...], "E": [...], "X": [[...] per Q]}
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

const input = JSON.parse(readFileSync(process.argv[2], "utf8"));
const mod = await import(pathToFileURL(input.js).href);
const p = mod.decodePayload(input.meta, mod.fromBase64(input.data));
const op = mod.makeOperator(p);
process.stdout.write(JSON.stringify({ B: Array.from(p.B || []), E: Array.from(p.E || []),
  X: input.Q.map((Q) => Array.from(op.evaluate(Q))) }));
