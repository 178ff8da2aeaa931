// Evaluate a multi-valued payload (defop.editor.payload.branched_to_payload) with the page's own module in Node.
// usage: node eval_branched.mjs input.json  ->  {"branches": [[X per Q] per branch], "follow": [{branch, X}],
//   "global": [branch per Q], "jumps": [[frame, from, to]], "g": [g_b per Q], "outside": [outside the box per Q]};
//   the follow run starts on branch 0 (reset()).
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

const input = JSON.parse(readFileSync(process.argv[2], "utf8"));
const mod = await import(pathToFileURL(input.js).href);
const p = mod.decodePayload(input.meta, mod.fromBase64(input.data));
const bop = mod.makeBranched(p);
const branches = bop.ops.map((op) => input.Q.map((Q) => Array.from(op.evaluate(Q))));
bop.reset();
const outside = [];
const follow = input.Q.map((Q) => {
  const X = Array.from(bop.evaluate(Q));
  outside.push(bop.outside);
  return { branch: bop.branch, X };
});
const jumps = bop.jumps;
const g = input.Q.map((Q) => Array.from(bop.estimates(Q).g));
bop.mode = "global";
const global = input.Q.map((Q) => bop.step(Q));
process.stdout.write(JSON.stringify({ branches, follow, global, jumps, g, outside }));
