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

/**
 * Region ℓ's vertices (sorted, a view), its patch (s members: `first` their index among p.members, `layout` the
 * (k × s) member vertices at each region vertex, PlacementRegions.layout) and its first bump row `offset`
 * (PlacementRegions.offset). In 2D every patch is its handle alone (s = 1).
 */
function regionSlices(p) {
  const out = [];
  for (let l = 0, o = 0, ov = 0, first = 0; l < p.region_sizes.length; l++) {
    const k = p.region_sizes[l], s = p.member_sizes[l];
    out.push({ vertices: p.region_vertices.subarray(ov, ov + k), offset: o, first, s,
      layout: p.layout.subarray(o, o + k * s), members: Array.from(p.members.subarray(first, first + s)) });
    o += k * s;
    ov += k;
    first += s;
  }
  return out;
}

/**
 * The bumps of region vertices idx (PlacementRegions.bumps_at): support (sorted vertices) and weights (s × B), one
 * column per patch member (B of them, region by region).
 */
function bumpsAt(p, regions, idx) {
  const B = p.members.length, w = new Map();
  regions.forEach((region, l) => {
    const pos = region.vertices.indexOf(idx[l]);
    for (let j = 0; j < region.s; j++) {
      const row = region.offset + pos * region.s + j;
      for (let k = p.bump_indptr[row]; k < p.bump_indptr[row + 1]; k++) {
        const v = p.bump_indices[k];
        if (!w.has(v)) w.set(v, new Float64Array(B));
        w.get(v)[region.first + j] = p.bump_data[k];
      }
    }
  });
  const sup = Int32Array.from([...w.keys()].sort((a, c) => a - c)), wt = new Float64Array(sup.length * B);
  sup.forEach((v, s) => wt.set(w.get(v), s * B));
  return { sup, wt };
}

/**
 * The movable operator of a payload (2D or 3D: D = p.d): evaluate(Q) at the current placement, setRest(ℓ, v, Q) to
 * move movable handle ℓ's rest position to vertex v of its region, its patch with it by one offset (a RangeError
 * naming the handle and the vertex when v is outside the region or holds another handle; nothing changes then),
 * placement() the current vertices. setRest updates the payload's P (rest positions of the moving handles) and
 * handles (their vertices) in place, so the editor draws and resets at the current placement; given Q (flat, the
 * editor's), it keeps q − p of every member (defop.operator.movable.retarget), and it returns the movable handle's
 * own shift (D numbers).
 */
export function makeMovable(p) {
  const D = p.d || 2, n = p.n_moving, nc = D * p.n_vertices, size = p.size, V = p.V, x = p.V, P = p.P;
  const mv = p.placement_movable, rows = p.movable_rows, nominal = p.nominal, b = mv.length, J = (b + n) * D;
  const memberRows = p.member_rows, nB = p.members.length;
  const A = p.A, B = p.B || null, r = B ? p.rank : nc;
  const fillPsi = makePsi({ kind: "tps", d: D, n_moving: b + n, P: new Float64Array(J), scale: 1, size,
    centers: p.joint_centers, kernel: p.kernel }); // pseudo-handles at 0, scale 1: Ψ of the joint z itself
  const regions = regionSlices(p), handles = p.handles;
  const movingHandles = [], fixed = [];
  for (let h = 0; h < handles.length; h++) (p.moving[h] ? movingHandles : fixed).push(h);
  const fixedVertices = Int32Array.from(fixed, (h) => handles[h]); // fixed handles never move
  const idx = Int32Array.from(nominal), hm = Int32Array.from(movingHandles, (h) => handles[h]);
  const cur = Int32Array.from(p.members, (h) => handles[h]); // every member's vertex (PlacementRegions.members_at)
  const z = new Float64Array(J), z0 = new Float64Array(J), psiZero = Float64Array.from(fillPsi(z0)).subarray(1);
  const psi0 = new Float64Array(size - 1), dpsi = new Float64Array(size - 1);
  const tmp = new Float64Array(r), out = new Float64Array(nc), res = new Float64Array(nB * D);
  let bumps = null;
  // a page of the drawn vertices only (defop.editor.movable_page.drawn_payload): p.drawn holds the operator's index
  // of each page vertex; setRest, checkRest and placement speak the operator's indices
  const ids = p.drawn || null, nAll = p.n_vertices_all || p.n_vertices, toMesh = (i) => (ids ? ids[i] : i);
  const toPage = (v) => {
    if (!ids) return v;
    let lo = 0, hi = ids.length - 1;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1;
      if (ids[mid] === v) return mid;
      if (ids[mid] < v) lo = mid + 1; else hi = mid - 1;
    }
    return -1;
  };

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
    for (let g = 0; g < nB; g++) for (let c = 0; c < D; c++) { // r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ), every member
      const j = D * memberRows[g] + c;
      res[D * g + c] = (Q[j] - P[j]) - out[D * cur[g] + c];
    }
    for (let c = 0; c < nc; c++) out[c] = x[c] + out[c];
    const { sup, wt } = bumps;
    for (let s = 0; s < sup.length; s++) for (let c = 0; c < D; c++) { // Σ_ℓ g_{v_ℓ} r_ℓ
      let t = 0;
      for (let g = 0; g < nB; g++) t += wt[s * nB + g] * res[D * g + c];
      out[D * sup[s] + c] += t;
    }
    for (let l = 0; l < n; l++) for (let c = 0; c < D; c++) out[D * hm[l] + c] = Q[D * l + c]; // Prop. 2
    for (const f of fixedVertices) for (let c = 0; c < D; c++) out[D * f + c] = x[D * f + c];
    return out;
  }

  /** Throws a RangeError unless vertex v is a place for movable handle ℓ's rest position. */
  function checkRest(l, v) {
    if (!Number.isInteger(l) || l < 0 || l >= b) throw new RangeError(`rest handle ${l}: there are ${b} movable handles (0..${b - 1})`);
    if (!Number.isInteger(v) || v < 0 || v >= nAll) {
      throw new RangeError(`rest handle ${l}: ${v} is not a vertex (0..${nAll - 1})`);
    }
    const i = toPage(v);
    for (let h = 0; h < handles.length; h++) {
      if (!regions[l].members.includes(h) && handles[h] === i) {
        throw new RangeError(`rest handle ${l} cannot move onto vertex ${v}: it holds handle ${h}; the rest handle stays`);
      }
    }
    if (i < 0 || regions[l].vertices.indexOf(i) < 0) {
      throw new RangeError(`vertex ${v} is outside rest handle ${l}'s placement region (${regions[l].vertices.length} ` +
        `vertices around vertex ${toMesh(nominal[l])}); the rest handle stays`);
    }
  }
  /** Move movable handle ℓ's rest position to vertex v and its patch with it (checked first: a RangeError changes
   * nothing); Q (optional, flat) keeps q − p of every member. Returns the handle's shift (D numbers). */
  function setRest(l, vertex, Q = null) {
    checkRest(l, vertex);
    const v = toPage(vertex), region = regions[l], pos = region.vertices.indexOf(v), shift = new Float64Array(D);
    for (let c = 0; c < D; c++) shift[c] = V[D * v + c] - V[D * idx[l] + c];
    idx[l] = v;
    for (let j = 0; j < region.s; j++) {
      const g = region.first + j, w = region.layout[pos * region.s + j], row = memberRows[g];
      for (let c = 0; c < D; c++) {
        if (Q) Q[D * row + c] = V[D * w + c] + (Q[D * row + c] - P[D * row + c]); // q − p stays (retarget): at rest, P
        P[D * row + c] = V[D * w + c];
      }
      cur[g] = w;
      hm[row] = w;
      handles[p.members[g]] = w;
    }
    settle();
    return shift;
  }
  return { evaluate, psi: (Q) => fillPsi(jointZ(Q, z)), setRest, checkRest, placement: () => Array.from(idx, toMesh),
    toMesh, regions, movable: mv, rows, n_movable: b, n_moving: n, n_vertices: p.n_vertices, d: D };
}

const MOVABLE_STYLE = `
.defop-editor .defop-rest-msg, .defop-solid .defop-rest-msg { color: #b00; font-weight: 600; min-height: 1.2em; }
.defop-editor .defop-rest-toggle[aria-pressed="true"], .defop-solid .defop-rest-toggle[aria-pressed="true"] {
  background: #2ca02c; color: #fff; }
`;

/** The nearest of `vertices` by dist(w): [vertex, distance]. */
function nearest(vertices, dist) {
  let best = -1, bestD = Infinity;
  for (const v of vertices) {
    const d = dist(v);
    if (d < bestD) { best = v; bestD = d; }
  }
  return [best, bestD];
}

/** dist(w): the distance of vertex w's current position (st.X, D = st.op.d) to a point (D numbers). */
const worldDistance = (st, point) => (w) => Math.hypot(...point.map((t, c) => st.X[st.op.d * w + c] - t));

/**
 * The vertex of rest handle ℓ's region nearest by dist (to the pointer or a point), within radius; a RangeError
 * saying why not: another handle (not of ℓ's patch) nearer and within radius (onto it), or no region vertex within
 * radius (outside; `where` names the place).
 */
function pickRest(st, l, dist, radius, where) {
  const region = st.op.regions[l], handles = st.p.handles;
  const [v, d] = nearest(region.vertices, dist);
  for (let h = 0; h < handles.length; h++) {
    const dh = dist(handles[h]);
    if (!region.members.includes(h) && dh <= radius && dh < d) {
      throw new RangeError(`rest handle ${l} cannot move onto handle ${h} (vertex ${handles[h]}); the rest handle stays`);
    }
  }
  if (d > radius) {
    throw new RangeError(`${where} is outside rest handle ${l}'s placement region (the green vertices); the rest ` +
      "handle stays");
  }
  return v;
}

/**
 * What the rest modes of the 2D and the 3D view share: the toggle ("move rest handle"), the message line (placed
 * by place(toggle, msg)), the state (st.restMode, st.restActive, st.restTarget), editor.setRest(ℓ, target) (target a
 * vertex index or a point of D numbers, snapped within snapRadius() to the region: pickRest) and the mover
 * move(ℓ, locate) that the pointer uses: locate() gives the vertex (the operator's index: op.toMesh) or throws; the
 * move is checked before anything changes (a RangeError is shown and changes nothing), keeps q − p (retarget),
 * then after(ℓ, shift), a redraw and hooks.onRest(placement, Q) unless notify is false. Returns { msg, move }.
 */
function restControls(editor, hooks, place, snapRadius, after = null) {
  const st = editor.st;
  addStyle("defop-movable-style", MOVABLE_STYLE);
  const toggle = el("button", { class: "defop-rest-toggle", "aria-pressed": "false",
    title: "drag a handle to move its rest position within its placement region (or Shift-drag)" }, "move rest handle");
  const msg = el("div", { class: "defop-rest-msg", role: "status" });
  place(toggle, msg);
  st.restMode = false;
  st.restActive = null;
  st.restTarget = null;
  toggle.addEventListener("click", () => {
    st.restMode = !st.restMode;
    toggle.setAttribute("aria-pressed", String(st.restMode));
  });
  const move = (l, locate, notify = true) => {
    try {
      const shift = st.op.setRest(l, locate(), st.Q); // checked first: a RangeError changes nothing
      if (after) after(l, shift);
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
  editor.setRest = (l, target, notify = true) => move(l, () => {
    if (!Array.isArray(target)) return target;
    if (target.length !== st.op.d || !target.every(Number.isFinite)) {
      throw new RangeError(`a rest position is ${st.op.d} finite numbers, got [${target.join(", ")}]; the rest ` +
        "handle stays");
    }
    const where = `(${target.map((t) => t.toFixed(3)).join(", ")})`;
    return st.op.toMesh(pickRest(st, l, worldDistance(st, target), snapRadius(), where));
  }, notify);
  return { msg, move };
}

/**
 * The rest mode's pointer on `box`, in the capture phase (before the view's own handle drag and orbit): a press with
 * the toggle on or Shift on a movable handle (near(ev)(w): a distance from the pointer to vertex w's position, within
 * radius()) picks it; a move shows the region vertex vertexAt(ℓ, ev) would place it at, or the message why not; the
 * release moves it there (move of restControls) or says why not, and nothing changes.
 */
function wireRestPointer(editor, box, canvas, { msg, move, near, radius, vertexAt }) {
  const st = editor.st;
  box.addEventListener("pointerdown", (ev) => {
    if (!(st.restMode || ev.shiftKey)) return;
    ev.stopPropagation();
    const handles = Array.from(st.op.movable, (h) => st.p.handles[h]);
    const [v, d] = nearest(handles, near(ev));
    if (d > radius()) { msg.textContent = "no movable handle here: press on a red handle with a green region"; return; }
    st.restActive = handles.indexOf(v);
    st.restTarget = { vertex: v };
    canvas.setPointerCapture(ev.pointerId);
    editor.evaluate(); // redraw with the target
  }, { capture: true });
  box.addEventListener("pointermove", (ev) => {
    if (st.restActive === null) return;
    ev.stopPropagation();
    try {
      st.restTarget = { vertex: vertexAt(st.restActive, ev) };
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
    if (!move(l, () => st.op.toMesh(vertexAt(l, ev)))) editor.evaluate();
  };
  box.addEventListener("pointerup", release, { capture: true });
  box.addEventListener("pointercancel", release, { capture: true });
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
  const p = st.p, owner = new Int32Array(p.n_vertices).fill(-1);
  const snapRadius = () => (p.pick_radius || 0.05) * st.view.diag;
  const { msg, move } = restControls(editor, hooks, (toggle, line) => {
    controls.append(toggle);
    controls.parentNode.insertBefore(line, controls.nextSibling);
  }, snapRadius, (l, shift) => { // the sampling regions travel with the rest
    for (const poly of p.regions[st.op.rows[l]]) {
      for (let i = 0; i < poly.length; i += 2) { poly[i] += shift[0]; poly[i + 1] += shift[1]; }
    }
  });
  st.op.regions.forEach((region, l) => region.vertices.forEach((v) => { owner[v] = l; }));
  const inside = []; // the triangles of the regions
  for (let t = 0; t < p.F.length / 3; t++) {
    const o = owner[p.F[3 * t]];
    if (o >= 0 && owner[p.F[3 * t + 1]] === o && owner[p.F[3 * t + 2]] === o) inside.push(t);
  }
  st.overlay = (ctx, s) => drawPlacement(ctx, s, inside);
  const position = (ev) => {
    const rect = canvas.getBoundingClientRect();
    return st.view.toData(ev.clientX - rect.left, ev.clientY - rect.top);
  };
  const near = (ev) => worldDistance(st, position(ev));
  /** The region vertex of rest handle ℓ at the pointer (deformed positions), or a RangeError saying why not. */
  const vertexAt = (l, ev) => {
    const [px, py] = position(ev);
    return pickRest(st, l, near(ev), snapRadius(), `(${px.toFixed(3)}, ${py.toFixed(3)})`);
  };
  // capture on the canvas' parent: in rest mode the moving-handle drag of defop_editor.js never sees the pointer
  wireRestPointer(editor, stack, canvas, { msg, move, near, radius: snapRadius, vertexAt });
  editor.evaluate();
  return editor;
}

const REST_PICK_PX = 14; // the 3D view picks a handle or a region vertex within this many CSS pixels (as defop_solid.js)

/**
 * The rest mode of the 3D view (createSolidView of defop_solid.js with makeMovable's operator): every placement
 * region's vertices drawn as small green balls (over the surface: interior vertices too), the toggle or Shift-drag on a
 * movable handle's sphere picks it, the drag shows where its patch would land (the region vertex nearest the pointer
 * on screen, within REST_PICK_PX, and every member's vertex there, larger green balls), the release places it; a release
 * on no region vertex, or nearer another handle, is refused with the message and nothing changes.
 * editor.setRest(ℓ, target) as in 2D (target: a vertex index or an [x, y, z] point).
 */
export function attachSolidRest(editor, hooks = {}) {
  if (!editor.webgl) return editor; // the page says in words that it cannot draw: nothing to drag
  const { ui, st, scene: sc } = editor, THREE = sc.THREE, p = st.p, canvas = sc.renderer.domElement;
  const { msg, move } = restControls(editor, hooks, (toggle, line) => { ui.reset.after(toggle); toggle.after(line); },
    () => (p.pick_radius || 0.05) * sc.diag);
  // balls (the vendored three.js has no point sprites), drawn over the surface (interior vertices are seen too), all
  // of one kind in one mesh: one draw call however large the region, few triangles a ball (a few pixels wide)
  const material = new THREE.MeshLambertMaterial({ color: 0x2ca02c, depthTest: false });
  const balls = (count, radius, segments) => {
    const ball = new THREE.SphereGeometry(radius * sc.diag, segments, segments - 2);
    const tpl = ball.attributes.position.array;
    const normal = ball.attributes.normal.array, index = ball.index.array, k = tpl.length / 3;
    const pos = new Float32Array(count * tpl.length), nrm = new Float32Array(count * tpl.length);
    const idx = new Uint32Array(count * index.length);
    for (let i = 0; i < count; i++) {
      nrm.set(normal, i * tpl.length);
      for (let j = 0; j < index.length; j++) idx[i * index.length + j] = index[j] + i * k;
    }
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(pos, 3).setUsage(THREE.DynamicDrawUsage));
    geometry.setAttribute("normal", new THREE.BufferAttribute(nrm, 3));
    geometry.setIndex(new THREE.BufferAttribute(idx, 1));
    const mesh = new THREE.Mesh(geometry, material);
    mesh.renderOrder = 2;
    mesh.frustumCulled = false;
    sc.scene.add(mesh);
    return { mesh, count: 0, place(vertices) { // a ball at the current position of each of `vertices`
      for (let i = 0; i < vertices.length; i++) {
        const w = 3 * vertices[i];
        for (let j = 0; j < tpl.length; j += 3) {
          for (let c = 0; c < 3; c++) pos[i * tpl.length + j + c] = tpl[j + c] + st.X[w + c];
        }
      }
      geometry.attributes.position.needsUpdate = true;
      geometry.setDrawRange(0, vertices.length * index.length);
      mesh.visible = vertices.length > 0;
      this.count = vertices.length;
    } };
  };
  const all = Int32Array.from(st.op.regions.flatMap((region) => Array.from(region.vertices)));
  const cloud = balls(all.length, 0.008, 4), target = balls(Math.max(...st.op.regions.map((r) => r.s)), 0.012, 10);
  editor.regionBalls = cloud;
  editor.overlay = () => {
    cloud.place(all);
    const t = st.restTarget, region = t && t.vertex !== null ? st.op.regions[st.restActive] : null;
    const pos = region ? region.vertices.indexOf(t.vertex) : -1;
    target.place(region ? region.layout.subarray(pos * region.s, (pos + 1) * region.s) : []);
  };
  const local = (ev) => { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; };
  const near = (ev) => {
    const uv = local(ev);
    return (w) => Math.hypot(...editor.vertexScreen(w).map((a, i) => a - uv[i]));
  };
  const vertexAt = (l, ev) => pickRest(st, l, near(ev), REST_PICK_PX, "the pointer");
  // capture on the view's box: before the handle drag of defop_solid.js and OrbitControls on the canvas
  wireRestPointer(editor, ui.box, canvas, { msg, move, near, radius: () => REST_PICK_PX, vertexAt });
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

MODES.movable = { makeOperator: makeMovable, attach: attachWidget, attachSolid: attachSolidRest };
