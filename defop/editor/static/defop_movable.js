// defop movable page: evaluates a MovableOp D(x; P, Q) ((M) of defop.operator.movable) in JavaScript, and the
// editor's rest mode, which moves a movable handle's rest position P within its placement region.
//
// The payload is written by defop.editor.movable_page.movable_to_payload. The formula is the Python frame's
// (defop.operator.movable: joint_z, MovableOp.delta_psi, correct):
//   z(P, Q) = [(P_b − P_b⁰)/s_P, (Q − P)/s_Q]   (the b movable handles' rest offsets, then the n moving handles)
//   δψ(P, Q) = (Ψ(z(P, Q))[1:] − Ψ(0)[1:]) − (Ψ(z(P, P))[1:] − Ψ(0)[1:])   (TPS over the joint space, makePsi)
//   u = δψ A B (float32 factors, products in float64), X = x + u
//   r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ),  X += Σ_ℓ g_{v_ℓ} r_ℓ on the bumps' support,  X[moving] = Q,  X[fixed] = x,
//   and a frame with Q = P returns x bit for bit (8b).
// The standalone page inlines defop_editor.js, then this file without its import line
// (defop.editor.movable_page.movable_script); Node tests import it as a module.
import { createEditor, decodePayload, fromBase64, makePsi, rowCombination, el, addStyle, MODES } from "./defop_editor.js";

/** Region ℓ's vertices (sorted, a view) and the offset of its first bump row (PlacementRegions.offset). */
function regionSlices(p) {
  const out = [];
  let o = 0;
  for (let l = 0; l < p.region_sizes.length; l++) {
    out.push({ vertices: p.region_vertices.subarray(o, o + p.region_sizes[l]), offset: o });
    o += p.region_sizes[l];
  }
  return out;
}

/** The bumps of region vertices idx (PlacementRegions.bumps_at): support (sorted vertices) and weights (s × b). */
function bumpsAt(p, regions, idx) {
  const b = idx.length, w = new Map();
  for (let l = 0; l < b; l++) {
    const row = regions[l].offset + regions[l].vertices.indexOf(idx[l]);
    for (let k = p.bump_indptr[row]; k < p.bump_indptr[row + 1]; k++) {
      const v = p.bump_indices[k];
      if (!w.has(v)) w.set(v, new Float64Array(b));
      w.get(v)[l] = p.bump_data[k];
    }
  }
  const sup = Int32Array.from([...w.keys()].sort((a, c) => a - c)), wt = new Float64Array(sup.length * b);
  sup.forEach((v, s) => wt.set(w.get(v), s * b));
  return { sup, wt };
}

/**
 * The movable operator of a payload: evaluate(Q) at the current placement, setRest(ℓ, v) to move movable handle
 * ℓ's rest position to vertex v of its region (a RangeError naming the handle and the vertex when v is outside the
 * region or holds another handle; nothing changes then), placement() the current vertices. setRest updates the
 * payload's P (rest positions of the moving handles) and handles (their vertices) in place, so the editor draws
 * and resets at the current placement.
 */
export function makeMovable(p) {
  const D = 2, n = p.n_moving, nc = D * p.n_vertices, size = p.size, V = p.V, x = p.V, P = p.P;
  const mv = p.placement_movable, rows = p.movable_rows, nominal = p.nominal, b = mv.length, J = (b + n) * D;
  const A = p.A, B = p.B || null, r = B ? p.rank : nc;
  const fillPsi = makePsi({ kind: "tps", d: D, n_moving: b + n, P: new Float64Array(J), scale: 1, size,
    centers: p.joint_centers, kernel: p.kernel }); // pseudo-handles at 0, scale 1: Ψ of the joint z itself
  const regions = regionSlices(p), handles = p.handles;
  const movingHandles = [], fixed = [];
  for (let h = 0; h < handles.length; h++) (p.moving[h] ? movingHandles : fixed).push(h);
  const fixedVertices = Int32Array.from(fixed, (h) => handles[h]); // fixed handles never move
  const idx = Int32Array.from(nominal), hm = Int32Array.from(movingHandles, (h) => handles[h]);
  const z = new Float64Array(J), z0 = new Float64Array(J), psiZero = Float64Array.from(fillPsi(z0)).subarray(1);
  const psi0 = new Float64Array(size - 1), dpsi = new Float64Array(size - 1);
  const tmp = new Float64Array(r), out = new Float64Array(nc), res = new Float64Array(b * D);
  let bumps = null;

  function jointZ(Q, zz) { // joint_z of defop.operator.movable
    for (let l = 0; l < b; l++) for (let c = 0; c < D; c++) {
      zz[D * l + c] = (V[D * idx[l] + c] - V[D * nominal[l] + c]) / p.s_p;
    }
    for (let l = 0; l < n; l++) for (let c = 0; c < D; c++) zz[D * (b + l) + c] = (Q[D * l + c] - V[D * hm[l] + c]) / p.s_q;
    return zz;
  }
  function deltaZ(zz, res_) { // HandleBasis.delta_z: Ψ(z)[1:] − Ψ(0)[1:]
    const psi = fillPsi(zz);
    for (let j = 0; j < size - 1; j++) res_[j] = psi[j + 1] - psiZero[j];
    return res_;
  }
  function settle() { // the placement's state (MovableOp.at): z(P, P), δψ's subtrahend, the bumps
    deltaZ(jointZ(P, z0), psi0);
    bumps = bumpsAt(p, regions, idx);
  }
  settle();

  function evaluate(Q) {
    let rest = true;
    for (let i = 0; i < D * n; i++) if (Q[i] !== P[i]) { rest = false; break; }
    if (rest) { out.set(x); return out; } // (8b): D(·; P, P) = x bit for bit
    deltaZ(jointZ(Q, z), dpsi);
    for (let j = 0; j < size - 1; j++) dpsi[j] -= psi0[j];
    if (B) rowCombination(rowCombination(dpsi, A, size - 1, r, tmp), B, r, nc, out); // u = δψ A B
    else rowCombination(dpsi, A, size - 1, nc, out);
    for (let l = 0; l < b; l++) for (let c = 0; c < D; c++) { // r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ)
      const j = D * rows[l] + c;
      res[D * l + c] = (Q[j] - P[j]) - out[D * idx[l] + c];
    }
    for (let c = 0; c < nc; c++) out[c] = x[c] + out[c];
    const { sup, wt } = bumps;
    for (let s = 0; s < sup.length; s++) for (let c = 0; c < D; c++) { // Σ_ℓ g_{v_ℓ} r_ℓ
      let t = 0;
      for (let l = 0; l < b; l++) t += wt[s * b + l] * res[D * l + c];
      out[D * sup[s] + c] += t;
    }
    for (let l = 0; l < n; l++) for (let c = 0; c < D; c++) out[D * hm[l] + c] = Q[D * l + c]; // Prop. 2
    for (const f of fixedVertices) for (let c = 0; c < D; c++) out[D * f + c] = x[D * f + c];
    return out;
  }

  /** Throws a RangeError unless vertex v is a place for movable handle ℓ's rest position. */
  function checkRest(l, v) {
    if (!Number.isInteger(l) || l < 0 || l >= b) throw new RangeError(`rest handle ${l}: there are ${b} movable handles (0..${b - 1})`);
    if (!Number.isInteger(v) || v < 0 || v >= p.n_vertices) {
      throw new RangeError(`rest handle ${l}: ${v} is not a vertex (0..${p.n_vertices - 1})`);
    }
    for (let h = 0; h < handles.length; h++) {
      if (h !== mv[l] && handles[h] === v) {
        throw new RangeError(`rest handle ${l} cannot move onto vertex ${v}: it holds handle ${h}; the rest handle stays`);
      }
    }
    if (regions[l].vertices.indexOf(v) < 0) {
      throw new RangeError(`vertex ${v} is outside rest handle ${l}'s placement region (${regions[l].vertices.length} ` +
        `vertices around vertex ${nominal[l]}); the rest handle stays`);
    }
  }
  /** Move movable handle ℓ's rest position to vertex v (checked first: a RangeError changes nothing). */
  function setRest(l, v) {
    checkRest(l, v);
    const row = rows[l];
    idx[l] = v;
    hm[row] = v;
    handles[mv[l]] = v;
    for (let c = 0; c < D; c++) P[D * row + c] = V[D * v + c];
    settle();
  }
  return { evaluate, psi: (Q) => fillPsi(jointZ(Q, z)), setRest, checkRest, placement: () => Array.from(idx),
    regions, movable: mv, rows, n_movable: b, n_moving: n, n_vertices: p.n_vertices, d: D };
}

const MOVABLE_STYLE = `
.defop-editor .defop-rest-msg { color: #b00; font-weight: 600; min-height: 1.2em; }
.defop-editor .defop-rest-toggle[aria-pressed="true"] { background: #2ca02c; color: #fff; }
`;

/** The nearest of `vertices` to (px, py) in positions X: [vertex, distance]. */
function nearest(vertices, X, px, py) {
  let best = -1, bestD = Infinity;
  for (const v of vertices) {
    const d = Math.hypot(X[2 * v] - px, X[2 * v + 1] - py);
    if (d < bestD) { best = v; bestD = d; }
  }
  return [best, bestD];
}

/** Draw every placement region on the mesh (its triangles green, its vertices as dots) and the snap target. */
function drawPlacement(ctx, st, inside) {
  const { view, p, X, op } = st;
  ctx.fillStyle = "rgba(44,160,44,0.25)";
  ctx.beginPath();
  for (const t of inside) {
    for (let k = 0; k < 3; k++) {
      const [u, v] = view.toScreen(X[2 * p.F[3 * t + k]], X[2 * p.F[3 * t + k] + 1]);
      if (k === 0) ctx.moveTo(u, v); else ctx.lineTo(u, v);
    }
    ctx.closePath();
  }
  ctx.fill();
  ctx.fillStyle = "#2ca02c";
  for (const region of op.regions) {
    for (const w of region.vertices) {
      const [u, v] = view.toScreen(X[2 * w], X[2 * w + 1]);
      ctx.fillRect(u - 2, v - 2, 4, 4);
    }
  }
  const target = st.restTarget;
  if (target && target.vertex !== null) {
    const [u, v] = view.toScreen(X[2 * target.vertex], X[2 * target.vertex + 1]);
    ctx.beginPath();
    ctx.arc(u, v, 8, 0, 2 * Math.PI);
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#2ca02c";
    ctx.stroke();
  }
}

/**
 * The rest mode of an editor whose operator is makeMovable's: a toggle ("move rest handle") and Shift-drag pick a
 * movable handle and move its rest position, snapped to the nearest vertex of its placement region (the drag shows
 * the target; the release places it). While deformed, q − p stays (defop.operator.movable.retarget). A bad place
 * (outside the region, onto another handle) is refused with a message and nothing changes.
 * editor.setRest(ℓ, target) does the same from code (target: a vertex index or an [x, y] point); it returns
 * whether the handle moved. hooks.onRest(placement, Q) is told of every move (notify = false: not).
 */
export function attachRestMode(editor, hooks = {}) {
  const { ui, st } = editor, canvas = ui.canvas, stack = canvas.parentNode, controls = ui.reset.parentNode;
  addStyle("defop-movable-style", MOVABLE_STYLE);
  const toggle = el("button", { class: "defop-rest-toggle", "aria-pressed": "false",
    title: "drag a handle to move its rest position within its placement region (or Shift-drag)" }, "move rest handle");
  const msg = el("div", { class: "defop-rest-msg", role: "status" });
  controls.append(toggle);
  controls.parentNode.insertBefore(msg, controls.nextSibling);
  const p = st.p, owner = new Int32Array(p.n_vertices).fill(-1);
  st.op.regions.forEach((region, l) => region.vertices.forEach((v) => { owner[v] = l; }));
  const inside = []; // the triangles of the regions
  for (let t = 0; t < p.F.length / 3; t++) {
    const o = owner[p.F[3 * t]];
    if (o >= 0 && owner[p.F[3 * t + 1]] === o && owner[p.F[3 * t + 2]] === o) inside.push(t);
  }
  st.restMode = false;
  st.restActive = null;
  st.restTarget = null;
  st.overlay = (ctx, s) => drawPlacement(ctx, s, inside);
  toggle.addEventListener("click", () => {
    st.restMode = !st.restMode;
    toggle.setAttribute("aria-pressed", String(st.restMode));
  });
  const snapRadius = () => (p.pick_radius || 0.05) * st.view.diag;

  /** The region vertex of rest handle ℓ at point (px, py) (deformed positions), or a RangeError saying why not. */
  function vertexAt(l, px, py) {
    const [v, d] = nearest(st.op.regions[l].vertices, st.X, px, py);
    const movable = st.op.movable[l];
    for (let h = 0; h < p.handles.length; h++) {
      const w = p.handles[h], dh = Math.hypot(st.X[2 * w] - px, st.X[2 * w + 1] - py);
      if (h !== movable && dh <= snapRadius() && dh < d) {
        throw new RangeError(`rest handle ${l} cannot move onto handle ${h} (vertex ${w}); the rest handle stays`);
      }
    }
    if (d > snapRadius()) {
      throw new RangeError(`(${px.toFixed(3)}, ${py.toFixed(3)}) is outside rest handle ${l}'s placement region ` +
        `(the green vertices); the rest handle stays`);
    }
    return v;
  }

  editor.setRest = (l, target, notify = true) => {
    try {
      const v = Array.isArray(target) ? vertexAt(l, target[0], target[1]) : target;
      const row = st.op.rows[l], old = st.op.placement()[l];
      st.op.setRest(l, v); // checked first: a RangeError changes nothing
      const dx = p.V[2 * v] - p.V[2 * old], dy = p.V[2 * v + 1] - p.V[2 * old + 1];
      st.Q[2 * row] += dx; // q − p stays (retarget)
      st.Q[2 * row + 1] += dy;
      for (const poly of p.regions[row]) for (let i = 0; i < poly.length; i += 2) { poly[i] += dx; poly[i + 1] += dy; }
      msg.textContent = "";
      editor.evaluate();
      if (notify && hooks.onRest) hooks.onRest(st.op.placement(), Array.from(st.Q));
      return true;
    } catch (err) {
      if (!(err instanceof RangeError)) throw err;
      msg.textContent = err.message;
      return false;
    }
  };

  const position = (ev) => {
    const rect = canvas.getBoundingClientRect();
    return st.view.toData(ev.clientX - rect.left, ev.clientY - rect.top);
  };
  // capture on the canvas' parent: in rest mode the moving-handle drag of defop_editor.js never sees the pointer
  stack.addEventListener("pointerdown", (ev) => {
    if (!(st.restMode || ev.shiftKey)) return;
    ev.stopPropagation();
    const [px, py] = position(ev);
    const handles = Array.from(st.op.movable, (h) => p.handles[h]);
    const [v, d] = nearest(handles, st.X, px, py);
    if (d > snapRadius()) { msg.textContent = "no movable handle here: press on a red handle with a green region"; return; }
    st.restActive = handles.indexOf(v);
    st.restTarget = { vertex: v };
    canvas.setPointerCapture(ev.pointerId);
  }, { capture: true });
  stack.addEventListener("pointermove", (ev) => {
    if (st.restActive === null) return;
    ev.stopPropagation();
    const [px, py] = position(ev);
    try {
      st.restTarget = { vertex: vertexAt(st.restActive, px, py) };
      msg.textContent = "";
    } catch (err) {
      if (!(err instanceof RangeError)) throw err;
      st.restTarget = { vertex: null };
      msg.textContent = err.message;
    }
    editor.evaluate(); // redraw with the target
  }, { capture: true });
  const release = (ev) => {
    if (st.restActive === null) return;
    ev.stopPropagation();
    const l = st.restActive;
    st.restActive = null;
    st.restTarget = null;
    if (!editor.setRest(l, position(ev))) editor.evaluate();
  };
  stack.addEventListener("pointerup", release, { capture: true });
  stack.addEventListener("pointercancel", release, { capture: true });
  editor.evaluate();
  return editor;
}

/** The standalone page of a MovableOp (defop.editor.movable_page.movable_html). */
export function mountMovable(root, meta, base64) {
  const editor = createEditor(root, decodePayload(meta, fromBase64(base64)), {}, { standalone: true,
    makeOperator: makeMovable });
  return attachRestMode(editor);
}

/**
 * The rest mode in the anywidget view (defop.editor.browser.BrowserEditor, trait `rest`): a move in the page sets
 * `rest` (Python's state places it and sends `q`, or refuses and sends both back); a `rest` set in Python is placed here
 * and Q taken from `q` (Python retargets it).
 */
function attachWidget(editor, model) {
  // only `rest`: Python retargets Q by the same arithmetic (retarget) and sends `q` back
  attachRestMode(editor, { onRest: (placement) => { model.set("rest", placement); model.save_changes(); } });
  const follow = () => {
    const rest = model.get("rest") || [], now = editor.st.op.placement();
    rest.forEach((v, l) => { if (v !== now[l]) editor.setRest(l, v, false); });
    const q = model.get("q");
    if (q.length === editor.st.Q.length) editor.st.Q = Float64Array.from(q);
    editor.evaluate();
  };
  follow();
  model.on("change:rest", follow);
}

MODES.movable = { makeOperator: makeMovable, attach: attachWidget };
