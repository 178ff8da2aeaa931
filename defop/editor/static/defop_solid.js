// defop in-page view of a 3D operator (tetrahedra): the surface shaded, an orbit camera, handles as spheres
// dragged in the view plane, and a reset button. The surface is the user's own, embedded in the tetrahedra
// (EmbeddedSurface of defop.geometry.volumetric.surface: fixed barycentric coordinates in one tetrahedron per
// vertex), evaluated after the tetrahedra's vertices every frame; without one, the boundary facets of the
// tetrahedra. Without WebGL the page says so in words (.defop-nowebgl). three.js draws; the operator is evaluated
// by the one evaluator of defop_editor.js (makeOperator, d = 3), so the page computes what the 2D editor computes.
//
// Used by the standalone page (defop.editor.export.to_html for a 3D operator): the page inlines three.js and its
// OrbitControls (vendored in static/three/, see its README), then defop_editor.js and this file (its import line
// removed: the names are in the same module scope), then calls mountSolid(root, meta, base64, THREE, OrbitControls).
// three.js is passed in, not imported, so this module loads anywhere defop_editor.js does.
//
// A drag: pointerdown on a moving handle (nearest in screen space within PICK_PX) fixes the plane through its
// current position, normal to the camera's viewing direction; every animation frame the pointer's ray meets
// that plane at the new handle position q, the operator is evaluated at Q, and the mesh and spheres follow.
// The orbit camera is disabled while a handle is held. Reset returns Q to P (the rest pose, exact: (8b)).

import { addStyle, decodePayload, dragLoop, el, extrapolating, fromBase64, makeOperator, MODES, timingText, warnText }
  from "./defop_editor.js";

const PICK_PX = 14; // a handle is picked within this many CSS pixels of its centre
const SOLID_STYLE = `
.defop-solid { display: flex; flex-wrap: wrap; gap: 12px; align-items: flex-start; font: 13px system-ui, sans-serif; color: #222; }
.defop-solid canvas.defop-canvas { border: 1px solid #ccc; touch-action: none; cursor: grab; display: block; }
.defop-solid .defop-side { display: flex; flex-direction: column; gap: 8px; width: 300px; }
.defop-solid .defop-readout { font-family: ui-monospace, monospace; font-size: 12px; white-space: pre-wrap; }
.defop-solid .defop-warn { color: #b00; font-weight: 600; min-height: 1.2em; }
.defop-solid details summary { cursor: pointer; color: #555; }
.defop-solid .defop-nowebgl { width: 720px; padding: 24px; border: 1px solid #b00; color: #b00; font-weight: 600; }
`;

function solidLayout(root) {
  addStyle("defop-solid-style", SOLID_STYLE);
  const box = el("div", { class: "defop-solid" });
  const canvas = el("canvas", { class: "defop-canvas" });
  const side = el("div", { class: "defop-side" });
  const reset = el("button", { class: "defop-reset" }, "Reset");
  const warn = el("div", { class: "defop-warn" });
  const readout = el("div", { class: "defop-readout" });
  const details = el("details", { class: "defop-details" });
  details.append(el("summary", {}, "details: frame rate, timings, handle positions"), readout);
  side.append(reset, warn, details);
  box.append(canvas, side);
  root.appendChild(box);
  return { box, canvas, reset, warn, readout };
}

/** Bounding box centre and diagonal of the rest vertices (flat xyz). */
function bounds(V) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < V.length; i += 3) {
    for (let c = 0; c < 3; c++) { lo[c] = Math.min(lo[c], V[i + c]); hi[c] = Math.max(hi[c], V[i + c]); }
  }
  return { center: lo.map((l, c) => (l + hi[c]) / 2), diag: Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) };
}

/**
 * The surface the page shades: `F` (flat triangles), `count` vertices and `evaluate(X)` -> their positions (flat
 * xyz, float64) from the tetrahedra's vertices X. The user's surface when the payload carries one (keys
 * surface_F, surface_tets, surface_bary of defop.editor.payload.surface_payload): vertex s is
 * Σ_k b_k X[t_k] over the 4 vertices t_k of its tetrahedron, b_0 = 1 − b_1 − b_2 − b_3 (EmbeddedSurface.deform);
 * a one-hot b gives X[t_k] exactly, so a handle on the surface lands exactly where the handle vertex does.
 * Otherwise the boundary facets of the tetrahedra (payload F) on X itself.
 */
export function makeSurface(p) {
  if (!p.surface_F) return { F: p.F, count: p.n_vertices, embedded: false, evaluate: (X) => X };
  const T = p.surface_tets, B = p.surface_bary, k = T.length / 4, S = new Float64Array(3 * k);
  const evaluate = (X) => {
    for (let s = 0; s < k; s++) {
      const b1 = B[3 * s], b2 = B[3 * s + 1], b3 = B[3 * s + 2], b0 = 1 - b1 - b2 - b3;
      const t0 = 3 * T[4 * s], t1 = 3 * T[4 * s + 1], t2 = 3 * T[4 * s + 2], t3 = 3 * T[4 * s + 3];
      for (let c = 0; c < 3; c++) S[3 * s + c] = b0 * X[t0 + c] + b1 * X[t1 + c] + b2 * X[t2 + c] + b3 * X[t3 + c];
    }
    return S;
  };
  return { F: p.surface_F, count: k, embedded: true, evaluate };
}

/** The three.js scene: shaded surface, handle spheres, a head light; camera and orbit controls. */
function makeScene(THREE, OrbitControls, canvas, p, width, height) {
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
  renderer.setPixelRatio((typeof window !== "undefined" && window.devicePixelRatio) || 1);
  renderer.setSize(width, height);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xffffff);
  const { center, diag } = bounds(p.V);
  const camera = new THREE.PerspectiveCamera(35, width / height, diag / 100, diag * 100);
  camera.position.set(center[0] + 0.9 * diag, center[1] + 0.6 * diag, center[2] + 1.6 * diag);
  scene.add(camera);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8a8a, 1.4));
  const light = new THREE.DirectionalLight(0xffffff, 2.0); // a head light: the shading follows the orbit
  light.position.set(0.5, 1, 1);
  camera.add(light);
  const surface = makeSurface(p);
  const positions = new Float32Array(surface.evaluate(p.V)); // the surface's vertices, indexed by its triangles
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3).setUsage(THREE.DynamicDrawUsage));
  geometry.setIndex(new THREE.BufferAttribute(Uint32Array.from(surface.F), 1));
  geometry.computeVertexNormals(); // shared vertices: smooth shading (normals averaged over the triangles)
  const material = new THREE.MeshLambertMaterial({ color: 0xf2d7a6 });
  const mesh = new THREE.Mesh(geometry, material);
  mesh.frustumCulled = false; // the bounding sphere is the rest pose's; the deformed mesh may leave it
  scene.add(mesh);
  const ball = new THREE.SphereGeometry(0.02 * diag, 20, 14);
  // handles are drawn over the surface (no depth test): a handle behind a limb stays visible and draggable
  const handleMaterial = (color, emissive = 0x000000) =>
    new THREE.MeshStandardMaterial({ color, emissive, roughness: 0.5, depthTest: false });
  const colours = { moving: handleMaterial(0xd62728), fixed: handleMaterial(0x1f77b4),
    outside: handleMaterial(0x4a0000, 0x660000) };
  const spheres = Array.from(p.handles, (_, h) => {
    const s = new THREE.Mesh(ball, p.moving[h] ? colours.moving : colours.fixed);
    s.renderOrder = 1;
    scene.add(s);
    return s;
  });
  const controls = new OrbitControls(camera, canvas);
  controls.target.set(...center);
  controls.update();
  return { THREE, renderer, scene, camera, controls, geometry, positions, surface, spheres, colours, diag };
}

/**
 * Mount the 3D view of a decoded payload `p` (d = 3) in `root`. Returns the editor object (also root.defopEditor):
 * st.Q, st.X (flat, 3·n_vertices: the vertices the surface uses, defop.editor.compact.drawn_vertices),
 * st.S (the drawn surface's vertices, flat, float64), st.frames / st.updates / st.evalMs / st.drawMs as in the 2D editor,
 * evaluate(), reset(), handleScreen(i) and vertexScreen(w) (CSS pixels in the canvas), camera, controls.
 * options.makeOperator: another evaluator of the payload (makeMovable of defop_movable.js); editor.overlay(), when
 * set, runs before every render (the movable page's region balls).
 */
export function createSolidView(root, p, THREE, OrbitControls, options = {}) {
  if (p.d !== 3) throw new Error(`the 3D view needs a payload with d = 3, got d = ${p.d}`);
  const ui = solidLayout(root), make = options.makeOperator || makeOperator;
  const width = options.width || 720, height = options.height || 540;
  let sc;
  try {
    sc = makeScene(THREE, OrbitControls, ui.canvas, p, width, height);
  } catch (err) {
    return withoutWebGL(root, ui, p, err, make);
  }
  const op = make(p);
  const st = { p, op, Q: Float64Array.from(p.P), X: null, S: null, active: null, outside: [], frames: [], updates: [],
    evalMs: [], drawMs: [], surfaceTriangles: sc.surface.F.length / 3 };
  const editor = { ui, st, scene: sc, camera: sc.camera, controls: sc.controls, webgl: true };

  const draw = () => {
    const X = st.X, pos = sc.positions, S = sc.surface.evaluate(X);
    st.S = S;
    for (let i = 0; i < pos.length; i++) pos[i] = S[i];
    sc.geometry.attributes.position.needsUpdate = true;
    sc.geometry.computeVertexNormals();
    const out = new Set(st.outside);
    let k = 0;
    p.handles.forEach((v, h) => {
      sc.spheres[h].position.set(X[3 * v], X[3 * v + 1], X[3 * v + 2]);
      if (p.moving[h]) { sc.spheres[h].material = out.has(k) ? sc.colours.outside : sc.colours.moving; k += 1; }
    });
    if (editor.overlay) editor.overlay();
    sc.renderer.render(sc.scene, sc.camera);
  };
  editor.render = () => sc.renderer.render(sc.scene, sc.camera);

  editor.evaluate = () => {
    const t0 = performance.now();
    st.X = op.evaluate(st.Q);
    const t1 = performance.now();
    st.outside = extrapolating(st.Q, p);
    draw();
    st.evalMs.push(t1 - t0);
    st.drawMs.push(performance.now() - t1);
    if (st.evalMs.length > 120) { st.evalMs.shift(); st.drawMs.shift(); }
    editor.readout();
  };
  editor.readout = () => solidReadout(ui, st);
  editor.reset = () => {
    st.Q = Float64Array.from(p.P);
    st.frames = [];
    st.updates = [];
    editor.evaluate();
  };
  ui.reset.addEventListener("click", editor.reset);
  /** Where vertex w's current position is drawn, in CSS pixels of the canvas. */
  editor.vertexScreen = (w) => {
    const X = st.X, q = new THREE.Vector3(X[3 * w], X[3 * w + 1], X[3 * w + 2]).project(sc.camera);
    return [((q.x + 1) / 2) * width, ((1 - q.y) / 2) * height];
  };
  /** Where the current position of moving handle i is drawn (its vertex: the payload's, which a rest move changes). */
  editor.handleScreen = (i) => editor.vertexScreen(Array.from(p.handles).filter((_, h) => p.moving[h])[i]);
  editor.cameraState = () => ({ matrixWorld: sc.camera.matrixWorld.elements.slice(),
    projectionMatrixInverse: sc.camera.projectionMatrixInverse.elements.slice(), width, height });
  wireSolidPointer(editor, sc, width, height);
  sc.controls.addEventListener("change", () => { if (st.active === null) editor.render(); });
  editor.evaluate();
  root.defopEditor = editor;
  return editor;
}

/**
 * The page without WebGL: the canvas gives way to a message in words, and the operator is still evaluated at
 * the rest pose (st.X), with nothing to drag.
 */
function withoutWebGL(root, ui, p, err, make) {
  const reason = err && err.message ? ` (${err.message})` : "";
  const note = el("div", { class: "defop-nowebgl", role: "alert" },
    "This page draws the 3D shape with WebGL, which this browser does not provide" + reason + ". Turn on " +
    "WebGL (hardware acceleration) in the browser's settings, or open the page in another browser.");
  ui.canvas.replaceWith(note);
  ui.reset.disabled = true;
  const op = make(p);
  const st = { p, op, Q: Float64Array.from(p.P), X: op.evaluate(p.P), S: null, active: null, outside: [], frames: [],
    updates: [], evalMs: [], drawMs: [], surfaceTriangles: makeSurface(p).F.length / 3 };
  st.S = makeSurface(p).evaluate(st.X);
  const editor = { ui, st, webgl: false, message: note };
  root.defopEditor = editor;
  return editor;
}

function solidReadout(ui, st) {
  const Q = st.Q;
  const q = Array.from({ length: st.p.n_moving },
    (_, i) => `q${i} = (${Q[3 * i].toFixed(3)}, ${Q[3 * i + 1].toFixed(3)}, ${Q[3 * i + 2].toFixed(3)})`);
  ui.readout.textContent = timingText(st) +
    `(|Ψ| = ${st.p.size}${st.p.B ? ", rank " + st.p.rank : ""}, ${st.p.n_vertices}${st.p.n_vertices_all ? " of " + st.p.n_vertices_all : ""} vertices, ` +
    `${st.surfaceTriangles} surface triangles)\n` + q.join("\n");
  ui.warn.textContent = warnText(st);
}

/**
 * Pointer events: pick the nearest moving handle on screen, fix the view plane through it, and move it to the
 * pointer ray's intersection with that plane once per animation frame (dragLoop of defop_editor.js, as in 2D);
 * orbit is disabled while a handle is held: this pointerdown listener is in the capture phase, so it runs before
 * OrbitControls' own, switches controls.enabled off and stops the event.
 */
function wireSolidPointer(editor, sc, width, height) {
  const { THREE } = sc, st = editor.st, canvas = sc.renderer.domElement;
  const raycaster = new THREE.Raycaster(), plane = new THREE.Plane(), hit = new THREE.Vector3();
  const ndc = new THREE.Vector2(), normal = new THREE.Vector3();
  const local = (ev) => { const r = canvas.getBoundingClientRect(); return [ev.clientX - r.left, ev.clientY - r.top]; };
  /** The pointer's ray (CSS pixels u, v) met with the drag plane, or null when parallel / behind. */
  const onPlane = (u, v) => {
    ndc.set((2 * u) / width - 1, 1 - (2 * v) / height);
    raycaster.setFromCamera(ndc, sc.camera);
    return raycaster.ray.intersectPlane(plane, hit) ? [hit.x, hit.y, hit.z] : null;
  };
  editor.onPlane = onPlane;
  const apply = (q) => { for (let c = 0; c < 3; c++) st.Q[3 * st.active + c] = q[c]; };
  const loop = dragLoop(editor, apply);
  canvas.addEventListener("pointerdown", (ev) => {
    const [u, v] = local(ev);
    let best = null, bestD = PICK_PX;
    for (let i = 0; i < st.p.n_moving; i++) {
      const [hu, hv] = editor.handleScreen(i);
      const dd = Math.hypot(hu - u, hv - v);
      if (dd <= bestD) { best = i; bestD = dd; }
    }
    if (best === null) return; // orbit
    sc.controls.enabled = false;
    ev.stopImmediatePropagation();
    st.active = best;
    sc.camera.getWorldDirection(normal);
    plane.setFromNormalAndCoplanarPoint(normal, new THREE.Vector3(...st.Q.slice(3 * best, 3 * best + 3)));
    editor.dragPlane = { normal: normal.toArray(), constant: plane.constant };
    canvas.setPointerCapture(ev.pointerId);
    loop.start();
  }, { capture: true });
  canvas.addEventListener("pointermove", (ev) => {
    if (st.active === null) return;
    const q = onPlane(...local(ev));
    if (q !== null) loop.move(q);
  });
  const release = (ev) => {
    if (st.active === null) return;
    const q = onPlane(...local(ev));
    if (q !== null) apply(q);
    st.active = null;
    loop.stop();
    sc.controls.enabled = true;
    editor.evaluate();
  };
  canvas.addEventListener("pointerup", release);
  canvas.addEventListener("pointercancel", release);
}

/**
 * The standalone 3D page (defop.editor.export.to_html for a 3D operator); a MovableOp's payload (`movable`) gets the
 * movable evaluator and rest mode that defop_movable.js, inlined after this file, registers (MODES.movable).
 */
export function mountSolid(root, meta, base64, THREE, OrbitControls) {
  const p = decodePayload(meta, fromBase64(base64)), mode = p.movable ? MODES.movable : null;
  if (p.movable && !mode) throw new Error("a movable payload needs defop_movable.js after defop_solid.js");
  const editor = createSolidView(root, p, THREE, OrbitControls, mode ? { makeOperator: mode.makeOperator } : {});
  return mode ? mode.attachSolid(editor) : editor;
}
