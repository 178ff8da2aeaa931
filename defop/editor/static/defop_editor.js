// defop in-page editor: evaluates a trained DefOp D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3) in JavaScript.
//
// One ES module, shared by three users (so there is one implementation of the formula):
//   - the anywidget view (defop.editor.browser.BrowserEditor): `export default { render }`;
//   - the standalone page (defop.editor.export.to_html): inlined, then `mountStandalone(meta, base64)`;
//   - the Node correctness tests (tests/test_browser_editor.py): `decodePayload` + `makeOperator`.
// A multi-valued operator (defop.operator.branched, payload.branched_to_payload) is one makeOperator per branch
// plus its closed-form domain test and energies (makeBranched): the standalone page drags it in `follow` mode.
// Nothing here touches the DOM at import time.
//
// The payload is written by defop.editor.payload.defop_to_payload: Ψ's kind, the rest positions P of the moving
// handles, the normalising scale, the TPS centres z_k = (Q_k − P)/scale or the monomial plan, and the
// float32 factors A ((|Ψ|−1) × r) and B (r × d·n_vertices) of W_F ≈ A B, or B absent and A = W_F
// ((|Ψ|−1) × d·n_vertices), evaluated as (★) of defop.operator.defop. Products accumulate in float64 (JavaScript numbers).
// d = 2 (triangles) or 3 (tetrahedra, payload scalar `d`); the radial kernel of "tps" follows
// defop.operator.handle_bases.KERNELS: r² log r in 2D, r³ in 3D (payload scalar `kernel`).
//
// A picture (defop.editor.payload.image_payload, optional): its PNG bytes and one texture coordinate per vertex (the rest
// vertex in the picture, v down). WebGL draws every deformed triangle with the picture's rest triangle mapped
// affinely onto it, the piecewise-affine warp of defop.view.warp.warp_image, at every pointer move.

const DTYPES = { f8: Float64Array, f4: Float32Array, i4: Int32Array, u2: Uint16Array, u1: Uint8Array };

/** Typed arrays from the payload's metadata and its byte buffer (ArrayBuffer, DataView or Uint8Array). */
export function decodePayload(meta, bytes) {
  const view = bytes instanceof ArrayBuffer ? new Uint8Array(bytes) : new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const buffer = view.slice().buffer; // an aligned private copy
  const p = { ...meta.scalars };
  for (const [name, a] of Object.entries(meta.arrays)) {
    p[name] = new DTYPES[a.dtype](buffer, a.offset, a.length);
    p[name + "_shape"] = a.shape;
  }
  return expandCompact(p);
}

/**
 * The standalone page's compact payload made whole (defop.editor.compact.compact_payload): B from its Rice codes
 * (B_rice, LSB first: per row j a unary quotient, a zero and B_k[j] low bits of the zigzag code) times
 * 2^B_exponent per row, exact in float32; E from F (2D).
 */
function expandCompact(p) {
  if (p.B_rice) {
    const rows = p.B_exponent.length, cols = (p.d || 2) * p.n_vertices, bytes = p.B_rice, end = 8 * bytes.length;
    const B = new Float32Array(rows * cols);
    let pos = 0;
    for (let j = 0, i = 0; j < rows; j++) {
      const s = 2 ** p.B_exponent[j], k = p.B_k[j];
      for (let c = 0; c < cols; c++, i++) {
        let q = 0, r = 0;
        while (pos < end && (bytes[pos >> 3] >> (pos & 7)) & 1) { q++; pos++; }
        pos++;
        for (let b = 0; b < k; b++, pos++) r |= ((bytes[pos >> 3] >> (pos & 7)) & 1) << b;
        const z = q * (1 << k) + r;
        B[i] = (z & 1 ? -(z + 1) / 2 : z / 2) * s;
      }
    }
    p.B = B;
  }
  if (!p.E && p.F && (p.d || 2) === 2) {
    const n = p.n_vertices, seen = new Set(), E = [];
    for (let t = 0; t < p.F.length; t += 3) {
      for (const [a, b] of [[p.F[t], p.F[t + 1]], [p.F[t + 1], p.F[t + 2]], [p.F[t + 2], p.F[t]]]) {
        const key = Math.min(a, b) * n + Math.max(a, b);
        if (!seen.has(key)) { seen.add(key); E.push(Math.min(a, b), Math.max(a, b)); }
      }
    }
    p.E = Int32Array.from(E);
  }
  return p;
}

/** Decode a base64 string into a Uint8Array (browser: atob; Node: Buffer). */
export function fromBase64(text) {
  if (typeof Buffer !== "undefined") return new Uint8Array(Buffer.from(text, "base64"));
  const bin = atob(text);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

/**
 * Ψ(Q) of defop.operator.handle_bases from a payload's basis keys (kind, P, scale, size, n_moving, d; centers and
 * kernel for "tps", parent/factor for the monomials): a function Q -> Float64Array(size), reused between calls.
 */
export function makePsi(p) {
  const D = p.d || 2, d = D * p.n_moving, size = p.size, P = p.P, scale = p.scale;
  const cubic = p.kernel === "r3"; // φ(r) = r³ (3D) instead of r² log r
  const z = new Float64Array(d), psi = new Float64Array(size);
  return function fillPsi(Q) {
    for (let i = 0; i < d; i++) z[i] = (Q[i] - P[i]) / scale;
    psi[0] = 1;
    if (p.kind === "tps") {
      const C = p.centers, m = size - 1 - d; // C: (m, D·n) normalised centres
      for (let i = 0; i < d; i++) psi[1 + i] = z[i];
      for (let k = 0; k < m; k++) {
        let r2 = 0;
        for (let i = 0; i < d; i++) { const t = z[i] - C[k * d + i]; r2 += t * t; }
        if (cubic) psi[1 + d + k] = r2 > 0 ? r2 * Math.sqrt(r2) : 0; // r³ = r² √r², φ(0) = 0
        else psi[1 + d + k] = r2 > 0 ? 0.5 * r2 * Math.log(r2) : 0; // r² log r = ½ r² log r², φ(0) = 0
      }
    } else {
      const parent = p.parent, factor = p.factor; // monomial j = monomial parent[j-1] · z[factor[j-1]]
      for (let j = 1; j < size; j++) psi[j] = psi[parent[j - 1]] * z[factor[j - 1]];
    }
    return psi;
  };
}

/** res = w @ M, M row-major (rows × cols), accumulated in float64 (JavaScript numbers). */
export function rowCombination(w, M, rows, cols, res) {
  res.fill(0);
  for (let j = 0; j < rows; j++) {
    const s = w[j];
    if (s === 0) continue;
    const o = j * cols;
    for (let c = 0; c < cols; c++) res[c] += s * M[o + c];
  }
  return res;
}

/**
 * The closed-form operator: psi(Q) and evaluate(Q) with the same formulas as defop.operator.handle_bases / DefOp.
 * Q is a flat array (D·n, D = 2 or 3) of the moving handles, row-major; evaluate returns a Float64Array
 * (D·n_vertices) that is reused between calls.
 */
export function makeOperator(p) {
  const D = p.d || 2, n = p.n_moving, size = p.size, nc = D * p.n_vertices;
  const P = p.P, A = p.A, B = p.B || null, r = B ? p.rank : nc, x = p.V;
  const fillPsi = makePsi(p);
  const dpsi = new Float64Array(size - 1);
  const tmp = new Float64Array(r), out = new Float64Array(nc);
  const movingVertices = Array.from(p.handles).filter((_, i) => p.moving[i]); // row l of Q is vertex movingVertices[l]
  const psi0 = Float64Array.from(fillPsi(P)).subarray(1); // Ψ(P)[1:], by the same code as every frame

  // (★) of defop.operator.defop: D(·, Q) = x + δψ(Q) W_F, then the moving handles' columns get Q − P exactly.
  // δψ(P) = 0 bit for bit (rest pose exact, 8b); W_F is zero on every handle column (Prop. 2).
  function evaluate(Q) {
    const psi = fillPsi(Q);
    for (let j = 0; j < size - 1; j++) dpsi[j] = psi[j + 1] - psi0[j];
    if (B) rowCombination(rowCombination(dpsi, A, size - 1, r, tmp), B, r, nc, out);
    else rowCombination(dpsi, A, size - 1, nc, out);
    for (let c = 0; c < nc; c++) out[c] += x[c];
    for (let l = 0; l < n; l++) {
      const v = movingVertices[l];
      for (let c = 0; c < D; c++) out[D * v + c] += Q[D * l + c] - P[D * l + c];
    }
    return out;
  }

  return { psi: fillPsi, evaluate, n_moving: n, n_vertices: p.n_vertices, d: D };
}

/** The payload of branch b of a multi-valued page: the shared mesh plus the keys written as `branch{b}.name`. */
export function branchPayload(p, b) {
  const q = { ...p }, pre = `branch${b}.`;
  for (const k of Object.keys(p)) if (k.startsWith(pre)) q[k.slice(pre.length)] = p[k];
  return q;
}

/**
 * The multi-valued operator of defop.operator.branched (a port of its closed forms, one makeOperator per branch):
 * E_b and s_b are ψ_b(Q) · (energy_w, score_w), the domain g_b is ψ_D(Q) · domain_w (its own TPS, or ψ_b for a
 * format-1 operator's λ²_b); b exists where g_b > 0 and (s_b ≥ 0 or s_b is
 * the largest side); `global` takes the existing branch of lowest E_b, `follow` (FollowSession.step) stays on its
 * branch while it exists and otherwise jumps there; where none exists, the largest g (far); outside the samples'
 * box, `outside`. evaluate(Q) steps
 * the current mode and evaluates that branch's D_b; reset() goes back to branch 0 (the rest pose's).
 */
export function makeBranched(p) {
  const nb = p.n_branches, ops = [], ws = [], doms = [];
  for (let b = 0; b < nb; b++) {
    const q = branchPayload(p, b);
    ops.push(makeOperator(q));
    ws.push([q.energy_w, q.domain_w, q.score_w]);
    // g_b: its own TPS (defop.operator.domains, format 2) or λ²_b on the branch's Ψ_b (format 1: null)
    doms.push(q.domain_own ? makePsi({ kind: "tps", d: q.d, n_moving: q.n_moving, P: q.P, size: q.domain_size,
      scale: q.domain_scale, centers: q.domain_centers, kernel: q.domain_kernel }) : null);
  }
  const box = p.box || null; // (2, D·n): lowest and highest Q − P of the samples, ± one spacing
  function outsideBox(Q) {
    if (!box) return false;
    for (let i = 0; i < dq; i++) { const t = Q[i] - p.P[i]; if (t < box[i] || t > box[dq + i]) return true; }
    return false;
  }
  function dot(a, w) { let t = 0; for (let j = 0; j < w.length; j++) t += a[j] * w[j]; return t; }
  const E = new Float64Array(nb), g = new Float64Array(nb), side = new Float64Array(nb);
  const dq = (p.d || 2) * p.n_moving;
  /** E_b, λ²_b, s_b at Q into fresh arrays, or a RangeError naming Q (wrong length, NaN, ±inf, Ψ(Q) overflowed). */
  function estimatesAt(Q) {
    if (!Q || Q.length !== dq) throw new RangeError(`Q must hold ${dq} numbers (the moving handles), got ${Q && Q.length}`);
    for (let i = 0; i < dq; i++) if (!Number.isFinite(Q[i])) throw new RangeError(`Q must be finite, got Q[${i}] = ${Q[i]}`);
    const e = new Float64Array(nb), l = new Float64Array(nb), s = new Float64Array(nb);
    for (let b = 0; b < nb; b++) {
      const psi = ops[b].psi(Q), out = [dot(psi, ws[b][0]), 0, dot(psi, ws[b][2])];
      out[1] = doms[b] ? dot(doms[b](Q), ws[b][1]) : dot(psi, ws[b][1]);
      if (!out.every(Number.isFinite)) throw new RangeError(`Ψ(Q) · (e, g, s) is not finite at Q = [${Array.from(Q)}]`);
      e[b] = out[0]; l[b] = out[1]; s[b] = out[2];
    }
    return { E: e, g: l, side: s };
  }
  /** E_b, g_b, s_b at Q (estimates() of Python), kept in bop's E, g, side only when Q is valid. */
  function estimates(Q) {
    const est = estimatesAt(Q);
    E.set(est.E); g.set(est.g); side.set(est.side);
    return { E, g, side };
  }
  function existing(est) {
    let top = -Infinity;
    for (let b = 0; b < nb; b++) top = Math.max(top, est.side[b]);
    return Array.from({ length: nb }, (_, b) => est.g[b] > 0 && (est.side[b] >= 0 || est.side[b] >= top));
  }
  function lowestExisting(est, ok) {
    let best = -1;
    for (let b = 0; b < nb; b++) if (ok[b] && (best < 0 || est.E[b] < est.E[best])) best = b;
    if (best >= 0) return { label: best, far: false };
    for (let b = 0; b < nb; b++) if (best < 0 || est.g[b] > est.g[best]) best = b;
    return { label: best, far: true };
  }
  const bop = { ops, n_branches: nb, labels: p.branch_labels || [...Array(nb).keys()], mode: "follow", branch: 0,
    far: false, outside: false, frame: 0, jumps: [], log: [], estimates };
  /** The next state at Q without changing anything (FollowSession._next): every check runs here. */
  function plan(Q) {
    const est = estimatesAt(Q), ok = existing(est), outside = outsideBox(Q);
    if (bop.mode !== "global" && ok[bop.branch]) return { est, label: bop.branch, far: false, outside, jump: null };
    const pick = lowestExisting(est, ok);
    const jump = bop.mode === "follow" && pick.label !== bop.branch ? [bop.frame, bop.branch, pick.label] : null;
    return { est, label: pick.label, far: pick.far, outside, jump };
  }
  function commit(next) {
    E.set(next.est.E); g.set(next.est.g); side.set(next.est.side);
    if (next.jump) bop.jumps.push(next.jump);
    bop.branch = next.label;
    bop.far = next.far;
    bop.outside = next.outside;
    bop.frame += 1;
    return bop.branch;
  }
  /** The label at Q in the current mode, updating the follow state (FollowSession.step); a rejected Q (a
   * RangeError) changes nothing. */
  bop.step = (Q) => commit(plan(Q));
  bop.evaluate = (Q) => {
    const next = plan(Q); // throws before any state changes
    const X = ops[next.label].evaluate(Q);
    commit(next);
    bop.log.push({ Q: Array.from(Q), branch: next.label, mode: bop.mode });
    if (bop.log.length > 10000) bop.log.shift();
    return X;
  };
  bop.reset = () => { bop.branch = 0; bop.frame = 0; bop.jumps = []; bop.log = []; bop.far = false; bop.outside = false; };
  bop.psi = (Q) => ops[bop.branch].psi(Q);
  return bop;
}

/** Even-odd point-in-polygon test; poly is a flat [x0, y0, x1, y1, ...] array. */
export function insidePolygon(x, y, poly) {
  let inside = false;
  for (let i = 0, k = poly.length / 2, j = k - 1; i < k; j = i++) {
    const xi = poly[2 * i], yi = poly[2 * i + 1], xj = poly[2 * j], yj = poly[2 * j + 1];
    if ((yi > y) !== (yj > y) && x < ((xj - xi) * (y - yi)) / (yj - yi) + xi) inside = !inside;
  }
  return inside;
}

/** Is (x, y, z) inside the ball [cx, cy, cz, radius]? (a 3D region, defop.editor.payload.region_balls) */
export function insideBall(x, y, z, ball) {
  return Math.hypot(x - ball[0], y - ball[1], z - ball[2]) <= ball[3];
}

/**
 * Indices of the moving handles outside their sampling region: the union of their region polygons (d = 2,
 * the default) or balls (d = 3).
 */
export function outsideRegions(Q, regions, d = 2) {
  const out = [];
  regions.forEach((polys, i) => {
    const inside = d === 3 ? (b) => insideBall(Q[3 * i], Q[3 * i + 1], Q[3 * i + 2], b)
      : (poly) => insidePolygon(Q[2 * i], Q[2 * i + 1], poly);
    if (polys.length && !polys.some(inside)) out.push(i);
  });
  return out;
}

/**
 * Indices of the moving handles where the operator extrapolates, by the rule of Python's ExtrapolationWarning
 * (defop.operator.core.beyond_reach): |q_i − P_i| > extrapolation_factor · reach_i + 1e-12, the factor and the
 * reach (farthest training sample per handle) from the payload (defop.editor.payload.extrapolation_payload);
 * none without a reach, as in Python.
 */
export function extrapolating(Q, p) {
  const D = p.d || 2, out = [];
  if (!p.reach) return out;
  for (let i = 0; i < p.n_moving; i++) {
    let s = 0;
    for (let c = 0; c < D; c++) { const t = Q[D * i + c] - p.P[D * i + c]; s += t * t; }
    if (Math.sqrt(s) > p.extrapolation_factor * p.reach[i] + 1e-12) out.push(i);
  }
  return out;
}

const STYLE = `
.defop-editor { display: flex; flex-wrap: wrap; gap: 12px; align-items: flex-start; font: 13px system-ui, sans-serif; color: #222; }
.defop-editor .defop-stack { position: relative; border: 1px solid #ccc; background: #fff; flex: none; }
.defop-editor .defop-stack canvas { position: absolute; left: 0; top: 0; }
.defop-editor .defop-canvas { touch-action: none; cursor: crosshair; }
.defop-editor .defop-gl { pointer-events: none; }
.defop-editor .defop-side { display: flex; flex-direction: column; gap: 8px; width: 300px; }
.defop-editor .defop-readout { font-family: ui-monospace, monospace; font-size: 12px; white-space: pre-wrap; }
.defop-editor .defop-warn { color: #b00; font-weight: 600; min-height: 1.2em; }
.defop-editor .defop-branch { font-weight: 600; font-size: 14px; }
.defop-editor details summary { cursor: pointer; color: #555; }
.defop-editor label { display: flex; gap: 6px; align-items: center; }
`;

/** A DOM element with attributes and text (shared with defop_solid.js). */
export function el(tag, attrs = {}, text = "") {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

/** Add a <style> with `css` to the document once (by `id`). */
export function addStyle(id, css) {
  if (document.getElementById(id)) return;
  const s = el("style", { id });
  s.textContent = css;
  document.head.appendChild(s);
}

function buildLayout(root, opts) {
  addStyle("defop-editor-style", STYLE);
  const box = el("div", { class: "defop-editor" });
  const stack = el("div", { class: "defop-stack" });
  const glCanvas = el("canvas", { class: "defop-gl" });
  const canvas = el("canvas", { class: "defop-canvas" });
  stack.append(glCanvas, canvas);
  const side = el("div", { class: "defop-side" });
  const title = el("div", { class: "defop-title" });
  const controls = el("div", { class: "defop-controls" });
  const basis = el("select", { class: "defop-basis", title: "handle basis Ψ" });
  const shape = el("select", { class: "defop-shape", title: "shape" });
  const reset = el("button", { class: "defop-reset" }, "Reset");
  const gtLabel = el("label", {}, "");
  const gt = el("input", { type: "checkbox", class: "defop-gt" });
  gtLabel.append(gt, document.createTextNode("ground truth (solved in Python)"));
  controls.append(basis, shape, reset);
  const warn = el("div", { class: "defop-warn" });
  const readout = el("div", { class: "defop-readout" });
  const branch = el("div", { class: "defop-branch" }); // a multi-valued page (makeBranched): the current branch
  const globalLabel = el("label", {}, "");
  const globalMode = el("input", { type: "checkbox", class: "defop-global" });
  globalLabel.append(globalMode, document.createTextNode("global: always the lowest-energy branch (no history)"));
  const gtReadout = el("div", { class: "defop-readout defop-gt-readout" });
  if (opts.standalone) { // the page states the title above the canvas; the numbers fold away behind a toggle
    title.style.display = "none";
    const details = el("details", { class: "defop-details" });
    details.append(el("summary", {}, "details: frame rate, timings, handle positions"), readout);
    side.append(title, controls, warn, details);
    if (opts.branched) side.insertBefore(branch, warn), side.insertBefore(globalLabel, warn);
  } else {
    side.append(title, controls, gtLabel, warn, readout, gtReadout);
  }
  if (!opts.kernel) { gtLabel.style.display = "none"; gtReadout.style.display = "none"; }
  box.append(stack, side);
  root.appendChild(box);
  return { box, canvas, glCanvas, title, basis, shape, reset, gt, warn, readout, gtReadout, branch, globalMode };
}

/** Canvas height (px) for `width`: the rest mesh plus the view's margin, between 320 and 560. */
function fitHeight(V, width, margin) {
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (let i = 0; i < V.length; i += 2) {
    x0 = Math.min(x0, V[i]); x1 = Math.max(x1, V[i]); y0 = Math.min(y0, V[i + 1]); y1 = Math.max(y1, V[i + 1]);
  }
  const pad = 2 * margin * Math.hypot(x1 - x0, y1 - y0);
  return Math.round(Math.min(560, Math.max(320, (width * (y1 - y0 + pad)) / (x1 - x0 + pad))));
}

/** Axis-aligned view: fits the rest mesh plus a margin into the canvas, y up. */
function makeView(V, width, height, margin) {
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (let i = 0; i < V.length; i += 2) {
    x0 = Math.min(x0, V[i]); x1 = Math.max(x1, V[i]); y0 = Math.min(y0, V[i + 1]); y1 = Math.max(y1, V[i + 1]);
  }
  const diag = Math.hypot(x1 - x0, y1 - y0), pad = margin * diag;
  const s = Math.min(width / (x1 - x0 + 2 * pad), height / (y1 - y0 + 2 * pad));
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return {
    diag, s,
    toScreen: (x, y) => [width / 2 + s * (x - cx), height / 2 - s * (y - cy)],
    toData: (u, v) => [cx + (u - width / 2) / s, cy + (height / 2 - v) / s],
  };
}

function tracePath(ctx, X, F, view, flippedOnly) {
  const { s } = view, [ox, oy] = view.toScreen(0, 0);
  ctx.beginPath();
  for (let t = 0; t < F.length; t += 3) {
    const a = 2 * F[t], b = 2 * F[t + 1], c = 2 * F[t + 2];
    if (flippedOnly !== null) {
      const area = (X[b] - X[a]) * (X[c + 1] - X[a + 1]) - (X[c] - X[a]) * (X[b + 1] - X[a + 1]);
      if ((area <= 0) !== flippedOnly) continue;
    }
    ctx.moveTo(ox + s * X[a], oy - s * X[a + 1]);
    ctx.lineTo(ox + s * X[b], oy - s * X[b + 1]);
    ctx.lineTo(ox + s * X[c], oy - s * X[c + 1]);
    ctx.closePath();
  }
}

function traceEdges(ctx, X, E, view) {
  const { s } = view, [ox, oy] = view.toScreen(0, 0);
  ctx.beginPath();
  for (let e = 0; e < E.length; e += 2) {
    const a = 2 * E[e], b = 2 * E[e + 1];
    ctx.moveTo(ox + s * X[a], oy - s * X[a + 1]);
    ctx.lineTo(ox + s * X[b], oy - s * X[b + 1]);
  }
}

function drawRegions(ctx, regions, view, fill = true) {
  ctx.fillStyle = fill ? "rgba(255,127,14,0.10)" : "rgba(0,0,0,0)";
  ctx.strokeStyle = "rgba(255,127,14,0.7)";
  ctx.lineWidth = 1;
  for (const polys of regions) {
    for (const poly of polys) {
      ctx.beginPath();
      for (let i = 0; i < poly.length; i += 2) {
        const [u, v] = view.toScreen(poly[i], poly[i + 1]);
        if (i === 0) ctx.moveTo(u, v); else ctx.lineTo(u, v);
      }
      ctx.closePath();
      ctx.fill();
      ctx.stroke();
    }
  }
}

function drawHandles(ctx, X, handles, moving, view, active, outside) {
  for (let h = 0; h < handles.length; h++) {
    const [u, v] = view.toScreen(X[2 * handles[h]], X[2 * handles[h] + 1]);
    ctx.beginPath();
    ctx.arc(u, v, 5, 0, 2 * Math.PI);
    ctx.fillStyle = moving[h] ? "#d62728" : "#1f77b4";
    ctx.fill();
    ctx.lineWidth = 1;
    ctx.strokeStyle = "#000";
    ctx.stroke();
  }
  const mov = [];
  for (let h = 0; h < handles.length; h++) if (moving[h]) mov.push(handles[h]);
  const ring = (i, radius, color) => {
    const [u, v] = view.toScreen(X[2 * mov[i]], X[2 * mov[i] + 1]);
    ctx.beginPath();
    ctx.arc(u, v, radius, 0, 2 * Math.PI);
    ctx.lineWidth = 2;
    ctx.strokeStyle = color;
    ctx.stroke();
  };
  for (const i of outside) ring(i, 9, "#b00");
  if (active !== null) ring(active, 8, "#000");
}

const VS = `attribute vec2 pos; attribute vec3 bc; attribute float fl; attribute vec2 uv; uniform vec4 xf;
varying vec3 bary; varying float flip; varying vec2 st;
void main() { bary = bc; flip = fl; st = uv; gl_Position = vec4((pos.x - xf.x) * xf.z, (pos.y - xf.y) * xf.w, 0.0, 1.0); }`;
// one pass draws fill (or the picture) and wireframe: a fragment is on an edge where a barycentric coordinate is ~0.
// The picture is sampled at the interpolated rest texture coordinate: affine on each triangle, as defop.view.warp does.
const FS = `#extension GL_OES_standard_derivatives : enable
#ifdef GL_FRAGMENT_PRECISION_HIGH
precision highp float; // texture coordinates of large pictures need more than mediump's 11 bits
#else
precision mediump float;
#endif
varying vec3 bary; varying float flip; varying vec2 st;
uniform vec4 fill; uniform vec4 flipped; uniform vec4 edge; uniform float edgesOnly; uniform float textured;
uniform sampler2D picture;
void main() {
  vec3 a = smoothstep(vec3(0.0), fwidth(bary), bary);
  float e = (1.0 - min(min(a.x, a.y), a.z)) * edge.a;
  if (edgesOnly > 0.5) { if (e < 0.02) discard; gl_FragColor = vec4(edge.rgb, e); return; }
  if (textured > 0.5) {
    vec4 t = texture2D(picture, st);
    vec3 c = flip > 0.5 ? mix(t.rgb, flipped.rgb, 0.6) : t.rgb;
    gl_FragColor = vec4(mix(c, edge.rgb, e), max(t.a, e));
    return;
  }
  gl_FragColor = vec4(mix(flip > 0.5 ? flipped.rgb : fill.rgb, edge.rgb, e), 1.0);
}`;

/**
 * WebGL renderer of the mesh (faces, flipped faces red, edges) and the ground truth's edges; null without WebGL.
 * setPicture(bitmap, uv) textures the faces with a picture (uv: one rest texture coordinate per vertex).
 */
function makeGL(canvas, p, view, width, height) {
  const gl = canvas.getContext("webgl", { antialias: false, premultipliedAlpha: false });
  if (!gl || !gl.getExtension("OES_standard_derivatives")) return null;
  const shader = (type, src) => { const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s); return s; };
  const prog = gl.createProgram();
  gl.attachShader(prog, shader(gl.VERTEX_SHADER, VS));
  gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, FS));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) return null;
  gl.useProgram(prog);
  const [ox, oy] = view.toData(width / 2, height / 2);
  gl.uniform4f(gl.getUniformLocation(prog, "xf"), ox, oy, (2 * view.s) / width, (2 * view.s) / height);
  const u = (name, ...v) => gl.uniform4f(gl.getUniformLocation(prog, name), ...v);
  u("fill", 0.949, 0.843, 0.651, 1);
  u("flipped", 0.878, 0.25, 0.25, 1);
  const edgesOnly = gl.getUniformLocation(prog, "edgesOnly"), textured = gl.getUniformLocation(prog, "textured");
  gl.uniform1f(textured, 0);
  gl.uniform1i(gl.getUniformLocation(prog, "picture"), 0);
  const F = p.F, nf = F.length / 3;
  const attribute = (name, size, data) => {
    const b = gl.createBuffer(), loc = gl.getAttribLocation(prog, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 0, 0);
    return b;
  };
  const bc = new Float32Array(9 * nf);
  for (let t = 0; t < nf; t++) { bc[9 * t] = 1; bc[9 * t + 4] = 1; bc[9 * t + 8] = 1; }
  attribute("bc", 3, bc);
  const corners = new Float32Array(6 * nf), flips = new Float32Array(3 * nf);
  const posBuf = attribute("pos", 2, corners), flipBuf = attribute("fl", 1, flips);
  const uvBuf = attribute("uv", 2, new Float32Array(6 * nf)); // zeros until a picture is set
  let hasPicture = false;
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
  gl.viewport(0, 0, canvas.width, canvas.height);
  const upload = (X) => { // one corner per triangle vertex; flipped = signed area <= 0
    for (let t = 0, k = 0; t < nf; t++) {
      const a = 2 * F[3 * t], b = 2 * F[3 * t + 1], c = 2 * F[3 * t + 2];
      corners[k++] = X[a]; corners[k++] = X[a + 1]; corners[k++] = X[b];
      corners[k++] = X[b + 1]; corners[k++] = X[c]; corners[k++] = X[c + 1];
      const f = (X[b] - X[a]) * (X[c + 1] - X[a + 1]) - (X[c] - X[a]) * (X[b + 1] - X[a + 1]) <= 0 ? 1 : 0;
      flips[3 * t] = f; flips[3 * t + 1] = f; flips[3 * t + 2] = f;
    }
    gl.bindBuffer(gl.ARRAY_BUFFER, posBuf);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, corners);
    gl.bindBuffer(gl.ARRAY_BUFFER, flipBuf);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, flips);
  };
  /** Upload the picture once (an ImageBitmap) and its texture coordinates per triangle corner; false if too large. */
  function setPicture(bitmap, uv) {
    if (Math.max(bitmap.width, bitmap.height) > gl.getParameter(gl.MAX_TEXTURE_SIZE)) return false;
    const tex = gl.createTexture();
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false); // row 0 of the picture at v = 0, as uv expects
    gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, bitmap);
    // any picture size (WebGL 1 without mipmaps): clamp and bilinear, like warp_image's map_coordinates(order=1)
    for (const [k, v] of [[gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE],
      [gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR]]) gl.texParameteri(gl.TEXTURE_2D, k, v);
    const uvc = new Float32Array(6 * nf);
    for (let t = 0, k = 0; t < 3 * nf; t++) { uvc[k++] = uv[2 * F[t]]; uvc[k++] = uv[2 * F[t] + 1]; }
    gl.bindBuffer(gl.ARRAY_BUFFER, uvBuf);
    gl.bufferSubData(gl.ARRAY_BUFFER, 0, uvc);
    hasPicture = true;
    return true;
  }
  function draw(X, gt) {
    gl.clearColor(1, 1, 1, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    upload(X);
    u("edge", 0, 0, 0, hasPicture ? 0.08 : 0.22); // faint mesh lines over the picture
    gl.uniform1f(edgesOnly, 0);
    gl.uniform1f(textured, hasPicture ? 1 : 0);
    gl.drawArrays(gl.TRIANGLES, 0, 3 * nf);
    if (gt) {
      upload(gt);
      u("edge", 0.12, 0.47, 0.71, 0.5);
      gl.uniform1f(edgesOnly, 1);
      gl.drawArrays(gl.TRIANGLES, 0, 3 * nf);
    }
  }
  return { draw, setPicture, renderer: "webgl" };
}

/** Decode PNG bytes into an ImageBitmap (no network and no <img>, so the standalone page's CSP holds). */
export function decodePicture(png) {
  const blob = new Blob([png], { type: "image/png" });
  return createImageBitmap(blob, { premultiplyAlpha: "none", colorSpaceConversion: "none" });
}

/** Draw one frame: regions, the deformed mesh (flipped triangles red), the ground truth, the handles. */
function drawFrame(ctx, st) {
  const { view, p, X } = st;
  ctx.clearRect(0, 0, st.width, st.height);
  if (st.gl) { // the mesh in WebGL, regions and handles on the 2D overlay
    st.gl.draw(X, st.gt && st.gtVisible ? st.gt : null);
    drawRegions(ctx, p.regions, view, false); // outlines only: the overlay is above the mesh
    if (st.overlay) st.overlay(ctx, st); // a mode's own marks under the handles (defop_movable.js)
    drawHandles(ctx, X, p.handles, p.moving, view, st.active, st.outside);
    return;
  }
  drawRegions(ctx, p.regions, view);
  tracePath(ctx, X, p.F, view, false);
  ctx.fillStyle = "#f2d7a6";
  ctx.fill();
  tracePath(ctx, X, p.F, view, true);
  ctx.fillStyle = "#e04040";
  ctx.fill();
  traceEdges(ctx, X, p.E, view);
  ctx.lineWidth = 0.5;
  ctx.strokeStyle = "rgba(0,0,0,0.25)";
  ctx.stroke();
  if (st.gt && st.gtVisible) {
    traceEdges(ctx, st.gt, p.E, view);
    ctx.strokeStyle = "rgba(31,119,180,0.55)";
    ctx.stroke();
  }
  if (st.overlay) st.overlay(ctx, st);
  drawHandles(ctx, X, p.handles, p.moving, view, st.active, st.outside);
}

function fillSelect(select, values, current) {
  select.textContent = "";
  for (const v of values) {
    const o = el("option", { value: v }, v);
    if (v === current) o.selected = true;
    select.appendChild(o);
  }
  select.style.display = values.length > 1 ? "" : "none";
}

/** Frames per second over a list of requestAnimationFrame timestamps (null below three). */
function rate(f) {
  return f.length > 2 ? (1000 * (f.length - 1)) / (f[f.length - 1] - f[0]) : null;
}

/**
 * The readout's timing lines (shared with defop_solid.js): the rate of frames the browser rendered while dragging
 * (every requestAnimationFrame callback, not the pointer events), how many of them showed a new deformation,
 * per-frame evaluation and drawing times.
 */
export function timingText(st) {
  const median = (a) => [...a].sort((x, y) => x - y)[Math.floor(a.length / 2)];
  const fmt = (v, digits) => (v === undefined || v === null ? "–" : v.toFixed(digits));
  return `${fmt(rate(st.frames), 0)} fps (frames the browser rendered while dragging)\n` +
    `${fmt(rate(st.updates), 0)} new deformations per second (one per pointer move)\n` +
    `evaluation ${fmt(median(st.evalMs), 2)} ms/frame in the page, drawing ${fmt(median(st.drawMs), 1)} ms\n`;
}

/** The extrapolation warning (shared with defop_solid.js), for the handles of {@link extrapolating}. */
export function warnText(st) {
  return st.outside.length ? `handle ${st.outside.join(", ")} beyond ${st.p.extrapolation_factor}× its farthest ` +
    "training sample: the operator extrapolates" : "";
}

/** The readout: timings ({@link timingText}), sizes, the picture, Q, and the extrapolation warning. */
function readout(ui, st) {
  const q = Array.from({ length: st.p.n_moving }, (_, i) => `q${i} = (${st.Q[2 * i].toFixed(3)}, ${st.Q[2 * i + 1].toFixed(3)})`);
  ui.readout.textContent = timingText(st) +
    `(|Ψ| = ${st.p.size}${st.p.B ? ", rank " + st.p.rank : ""}, ${st.p.n_vertices} vertices)\n` +
    (st.picture ? `picture ${st.picture.size[0]} × ${st.picture.size[1]} px: ${st.textured ? "textured (WebGL)" :
      st.picture.failed || "not drawn (needs WebGL)"}\n` : "") + q.join("\n");
  ui.warn.textContent = warnText(st);
  if (st.op.n_branches) {
    const b = st.op.branch;
    ui.branch.textContent = `branch ${st.op.labels[b]} (${st.op.mode}${st.op.mode === "follow" ?
      ", " + st.op.jumps.length + " jump" + (st.op.jumps.length === 1 ? "" : "s") : ""})`;
    ui.branch.dataset.branch = String(b);
    if (st.op.far) ui.warn.textContent = (ui.warn.textContent ? ui.warn.textContent + "; " : "") +
      "outside every branch's domain: the nearest branch extrapolates";
    if (st.op.outside) ui.warn.textContent = (ui.warn.textContent ? ui.warn.textContent + "; " : "") +
      "beyond the branches' samples (their box enlarged by one spacing): every branch extrapolates";
  }
}

/** Reset, basis and shape menus, ground-truth toggle: local redraw plus the kernel hooks, when connected. */
function wireControls(editor, ctx) {
  const { ui, st, hooks } = editor;
  ui.reset.addEventListener("click", () => {
    st.Q = Float64Array.from(st.p.P);
    st.frames = [];
    st.updates = [];
    if (st.op.reset) st.op.reset(); // a multi-valued page: back to the rest branch
    editor.evaluate();
    if (hooks.onReset) hooks.onReset();
  });
  ui.globalMode.addEventListener("change", () => {
    if (!st.op.n_branches) return;
    st.op.mode = ui.globalMode.checked ? "global" : "follow"; // follow resumes on the branch shown
    editor.evaluate();
  });
  ui.basis.addEventListener("change", () => hooks.onBasis && hooks.onBasis(ui.basis.value));
  ui.shape.addEventListener("change", () => hooks.onShape && hooks.onShape(ui.shape.value));
  ui.gt.addEventListener("change", () => {
    st.gtVisible = ui.gt.checked;
    drawFrame(ctx, st);
    if (hooks.onGroundTruth) hooks.onGroundTruth(ui.gt.checked);
  });
}

/**
 * Mount an editor in `root`. `hooks` (all optional) connect it to a kernel:
 * onRelease(Q), onBasis(kind), onShape(name), onGroundTruth(enabled), onReset().
 * Returns the editor object (also stored as root.defopEditor) with Q, X, stats and the view.
 */
export function createEditor(root, payload, hooks = {}, options = {}) {
  const ui = buildLayout(root, { kernel: !!hooks.onGroundTruth, standalone: !!options.standalone,
    branched: !!payload.n_branches });
  const width = options.width || 720;
  const dpr = (typeof window !== "undefined" && window.devicePixelRatio) || 1;
  const ctx = ui.canvas.getContext("2d");
  const st = { width, height: 0, active: null, outside: [], gt: null, gtVisible: false, frames: [], updates: [],
    evalMs: [], drawMs: [],
    picture: null, textured: false };
  const editor = { ui, st, hooks };
  const resize = (height) => { // the canvas follows the shape's aspect, so controls and readout stay in view
    for (const c of [ui.canvas, ui.glCanvas, ui.canvas.parentNode]) {
      if (c.tagName === "CANVAS") { c.width = Math.round(width * dpr); c.height = Math.round(height * dpr); }
      c.style.width = width + "px";
      c.style.height = height + "px";
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    st.height = height;
  };

  editor.load = (payload_, Q) => {
    const p = payload_;
    st.p = p;
    // several branches: the follow drag; options.makeOperator: another evaluator (defop_movable.js)
    st.op = options.makeOperator ? options.makeOperator(p) : p.n_branches ? makeBranched(p) : makeOperator(p);
    resize(options.height || fitHeight(p.V, width, 0.25));
    st.view = makeView(p.V, width, st.height, 0.25);
    st.gl = options.webgl === false ? null : makeGL(ui.glCanvas, p, st.view, width, st.height);
    st.textured = false;
    if (p.image_png) editor.setImage(p); // the standalone page carries its picture in the payload
    else applyPicture();
    st.Q = Float64Array.from(Q || p.P);
    st.gt = null;
    ui.title.textContent = p.title;
    fillSelect(ui.basis, p.kinds, p.kind);
    fillSelect(ui.shape, p.shapes || [], p.shape);
    editor.evaluate();
  };

  editor.evaluate = () => {
    const t0 = performance.now();
    st.X = st.op.evaluate(st.Q);
    const t1 = performance.now();
    st.outside = extrapolating(st.Q, st.p);
    drawFrame(ctx, st);
    st.evalMs.push(t1 - t0);
    st.drawMs.push(performance.now() - t1);
    if (st.evalMs.length > 120) { st.evalMs.shift(); st.drawMs.shift(); }
    editor.readout();
  };

  editor.readout = () => readout(ui, st);

  // the picture: decoded once, textured onto every mesh load (a basis switch rebuilds the WebGL renderer)
  const applyPicture = () => {
    const pic = st.picture;
    st.textured = false;
    if (!pic || !pic.bitmap || !st.gl) return;
    if (pic.uv.length !== 2 * st.p.n_vertices) { pic.failed = "not drawn (made for another mesh)"; return; }
    st.textured = st.gl.setPicture(pic.bitmap, pic.uv);
    if (!st.textured) pic.failed = "not drawn (larger than this GPU's textures)";
  };
  /** Show a picture on the mesh: img = {image_png, uv, image_size} (defop.editor.payload.image_payload), or null. */
  editor.setImage = (img) => {
    if (!img || !img.image_png) { st.picture = null; editor.imageReady = Promise.resolve(false); return editor.imageReady; }
    const pic = { uv: img.uv, size: img.image_size, bitmap: null, failed: null };
    st.picture = pic;
    editor.imageReady = decodePicture(img.image_png).then(
      (bitmap) => { pic.bitmap = bitmap; },
      (err) => { pic.failed = `not drawn (${err})`; },
    ).then(() => {
      if (st.picture !== pic) return false;
      applyPicture();
      if (st.p) editor.evaluate();
      return st.textured;
    });
    return editor.imageReady;
  };

  wirePointer(editor, ui.canvas);
  wireControls(editor, ctx);
  editor.setGroundTruth = (X, text) => {
    st.gt = X;
    ui.gtReadout.textContent = text || "";
    drawFrame(ctx, st);
  };
  editor.handleScreen = (i) => st.view.toScreen(st.Q[2 * i], st.Q[2 * i + 1]);
  editor.load(payload);
  root.defopEditor = editor;
  return editor;
}

/**
 * Pointer events: pick the nearest moving handle, evaluate once per animation frame, report on release. While a
 * handle is held, every animation frame is counted (st.frames: the rate the browser renders at), and those that
 * showed a new deformation too (st.updates).
 */
function wirePointer(editor, canvas) {
  const st = editor.st;
  const position = (ev) => {
    const r = canvas.getBoundingClientRect();
    return st.view.toData(ev.clientX - r.left, ev.clientY - r.top);
  };
  const loop = dragLoop(editor, (q) => { st.Q[2 * st.active] = q[0]; st.Q[2 * st.active + 1] = q[1]; });
  canvas.addEventListener("pointerdown", (ev) => {
    const [x, y] = position(ev);
    let best = null, bestD = (st.p.pick_radius || 0.05) * st.view.diag;
    for (let i = 0; i < st.p.n_moving; i++) {
      const dd = Math.hypot(st.Q[2 * i] - x, st.Q[2 * i + 1] - y);
      if (dd <= bestD) { best = i; bestD = dd; }
    }
    st.active = best;
    if (best !== null) {
      canvas.setPointerCapture(ev.pointerId);
      loop.start();
    }
  });
  canvas.addEventListener("pointermove", (ev) => {
    if (st.active === null) return;
    loop.move(position(ev));
  });
  const release = (ev) => {
    if (st.active === null) return;
    const [x, y] = position(ev);
    st.Q[2 * st.active] = x;
    st.Q[2 * st.active + 1] = y;
    st.active = null;
    loop.stop();
    editor.evaluate();
    if (editor.hooks.onRelease) editor.hooks.onRelease(Array.from(st.Q));
  };
  canvas.addEventListener("pointerup", release);
  canvas.addEventListener("pointercancel", release);
}

/**
 * The drag's animation-frame loop (shared with defop_solid.js). While a handle is held (st.active), every
 * animation frame is counted (st.frames: the rate the browser renders at); a frame with a new pointer position
 * applies it (`apply(q)` writes st.Q), evaluates, and is counted in st.updates too. start() on pointerdown,
 * move(q) on pointermove, stop() on release.
 */
export function dragLoop(editor, apply) {
  const st = editor.st;
  let pending = null, scheduled = false;
  const keep = (list, t) => { list.push(t); if (list.length > 120) list.shift(); };
  const frame = (t) => {
    scheduled = false;
    if (st.active === null) return;
    keep(st.frames, t);
    scheduled = true;
    requestAnimationFrame(frame); // the next frame, as long as the handle is held
    if (pending === null) { editor.readout(); return; }
    apply(pending);
    pending = null;
    keep(st.updates, t);
    editor.evaluate();
    if (editor.onFrame) editor.onFrame(t); // benchmarks log the rAF timestamp of every frame that evaluated
  };
  const schedule = () => { if (!scheduled) { scheduled = true; requestAnimationFrame(frame); } };
  return {
    start() { st.frames = []; st.updates = []; schedule(); },
    move(q) { pending = q; schedule(); },
    stop() { pending = null; },
  };
}

/** The standalone page (defop.editor.export.to_html): no kernel, one operator; its readout folds away. */
export function mountStandalone(root, meta, base64) {
  return createEditor(root, decodePayload(meta, fromBase64(base64)), {}, { standalone: true });
}

/** Other operators' editor modes, registered by the files inlined after this one (defop_movable.js: `movable`). */
export const MODES = {};

/** The anywidget view (defop.editor.browser.BrowserEditor). */
function render({ model, el: root }) {
  const payload = () => decodePayload(model.get("payload_meta"), model.get("payload_data"));
  const first = payload(), mode = first.movable ? MODES.movable : null; // a MovableOp: its rest mode
  const editor = createEditor(root, first, {
    onRelease: (Q) => { model.set("q", Q); model.save_changes(); },
    onBasis: (kind) => { model.set("basis", kind); model.save_changes(); },
    onShape: (name) => { model.set("shape_name", name); model.save_changes(); },
    onGroundTruth: (on) => { model.set("ground_truth", on); model.save_changes(); },
    onReset: () => { model.set("q", Array.from(editor.st.Q)); model.save_changes(); },
  }, mode ? { makeOperator: mode.makeOperator } : {});
  if (mode) mode.attach(editor, model);
  const gt = () => {
    const data = model.get("gt_data");
    const meta = model.get("gt_meta");
    const X = data && data.byteLength ? new Float32Array(new Uint8Array(data.buffer, data.byteOffset, data.byteLength).slice().buffer) : null;
    editor.setGroundTruth(X, meta.text || "");
  };
  const image = () => {
    const data = model.get("image_data");
    editor.setImage(data && data.byteLength ? decodePayload(model.get("image_meta"), data) : null);
  };
  image();
  model.on("change:image_data", image);
  model.on("change:payload_data", () => editor.load(payload(), model.get("q")));
  model.on("change:gt_data", gt);
  model.on("change:gt_meta", gt);
  model.on("change:q", () => {
    const q = model.get("q");
    if (editor.st.active === null && q.length === editor.st.Q.length) { editor.st.Q = Float64Array.from(q); editor.evaluate(); }
  });
  return () => root.replaceChildren();
}

export default { render };
