"""In-page editor benchmark (issue #18): frame rate of a scripted drag on the octopus in headless Chromium.

The octopus (about 3.9k vertices, 9 moving handles) with an S-ARAP TPS operator trained on a modest
m = 40 samples (the basis needs at least 2n + 2 = 20; ``python benchmarks/bench_browser.py [m]``), written
as a standalone page by :func:`defop.editor.export.to_html`. In the page, a 200-step drag of one handle is
scripted from ``requestAnimationFrame``: every animation frame dispatches one ``pointermove`` to the
canvas, so the editor has one new Q per frame; the frame timestamps are the rAF timestamps. Prints the
median and 5th-percentile frame rate and the editor's own median per-frame evaluation and drawing times.

Side by side, in the same run, today's ipympl editor :class:`defop.editor.widgets.HandleEditor` is dragged in
JupyterLab with the same operator and the same in-page scripted drag (mouse events, which ipympl listens
to); its frames are the images ipympl draws into its canvas (``drawImage`` wrapped), counted until the
kernel has caught up.

Target: >= 55 fps median in the page. Headless Chromium runs with ``--disable-gpu`` (WebGL through
SwiftShader) on a shared 2-core machine: timings are noisy, compare the two rows of one run. Needs
Debian's chromium, playwright and jupyterlab; ``--no-ipympl`` skips the JupyterLab part.

``--image``: the picture editor of notebook 13 instead (the horse, about 2k vertices, 6 moving handles, its
480 × 408 picture as a WebGL texture; ``python benchmarks/bench_browser.py --image [m] [n_vertices]``). The
same operator is written twice by :func:`defop.editor.export.to_html`, with and without the picture, and both pages
are dragged in one run: the rAF frame rate as above, and the frame time with the GPU's work forced to finish
(``evaluate()`` then a one-pixel ``readPixels``, so no vsync cap: evaluation, upload, rasterisation and texture
sampling, which SwiftShader does on the CPU), alternating the two pages three times.

``--movable``: the page of a :class:`~defop.operator.movable.MovableOp` (issue 44) on the octopus (handles 0, 3, 6
movable within 5% of the diagonal, as ``bench_movable.py``), its handle 0's rest position moved to the farthest
vertex of its region before the drag, beside the fixed-P page of a DefOp trained at the same m, both compressed
(the default tolerance), alternating the two pages: rAF frame rate, the forced frame time (as ``--image``) and the
page's evaluation time, and their ratios. ``python benchmarks/bench_browser.py --movable [m]`` (default m = 40,
small: the movable frame's |Ψ| is about twice m plus the rest centres).

``--movable --3d``: the same comparison in 3D on ``octopus_3d`` (handle 0 movable within 5% of the diagonal, its
rest moved to the farthest vertex of its region first): the 3D page of a MovableOp beside the 3D fixed-P page, both
of a trained operator's sizes with synthetic smooth factors of one rank (default m = 200, rank 105: the trained
octopus_3d's). ``python benchmarks/bench_browser.py --movable --3d [m] [rank]``.

``--3d``: the 3D page (issue 27, part 5) of the largest 3D model, ``octopus_3d`` (about 10.3k vertices, 44k
tetrahedra, 10.8k boundary triangles, 9 moving handles), written by :func:`defop.editor.export.to_html` and
dragged as above (one pointer event per animation frame on a handle; the handle moves in the view plane, the
page evaluates D(·, Q) for every vertex, recomputes the surface normals and renders with three.js).
``python benchmarks/bench_browser.py --3d [m] [rank]``. Training octopus_3d with S-ARAP takes about 90 s per
sample on this machine (about 45 min for the minimum m = 28 of TPS with 9 handles in 3D), so by default the
frame rate is measured with an operator *of the trained operator's exact sizes* (TPS basis with m centres drawn
in the model's sampling balls, W a smooth field: an affine map of the rest positions per basis function): the
page's work per frame depends only on |Ψ|, n_vertices, the rank and the surface, not on W's values.
``--trained`` trains the real operator instead (cached under DEFOP_CACHE). ``rank`` > 0 compresses W_F first.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import defop as dop
from defop.editor import export

CHROMIUM = os.environ.get("DEFOP_CHROMIUM") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-dev-shm-usage"]

DRAG = """async ([x0, y0, dx, dy, steps]) => {
  // one pointer step per animation frame, out and back; pointer and mouse events (ipympl listens to mouse ones)
  const target = document.elementFromPoint(x0, y0);
  const fire = (kind, x, y) => {
    const o = {clientX: x, clientY: y, pointerId: 1, isPrimary: true, bubbles: true, button: 0, buttons: 1};
    target.dispatchEvent(new PointerEvent("pointer" + kind, o));
    target.dispatchEvent(new MouseEvent("mouse" + kind, o));
  };
  fire("down", x0, y0);
  await new Promise((done) => {
    let k = 0;
    const step = () => {
      if (k === steps) { done(); return; }
      k += 1;
      const s = Math.sin((Math.PI * k) / steps);
      fire("move", x0 + s * dx, y0 + s * dy);
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  });
  fire("up", x0, y0);
}"""


def rates(stamps):
    """Median and 5th-percentile frame rate from frame timestamps (ms); draws < 2 ms apart are one frame."""
    t = np.asarray(stamps, float)
    t = t[np.concatenate([[True], np.diff(t) > 2.0])] if len(t) else t
    if len(t) < 3:
        return float("nan"), float("nan"), len(t), 0.0
    fps = 1000.0 / np.diff(t)
    return float(np.median(fps)), float(np.percentile(fps, 5)), len(t), (t[-1] - t[0]) / 1000


# frames with the GPU's work forced to finish: evaluate at a Q moved along a circle, then read one pixel back
SYNC_FRAMES = """(n) => {
  const e = window.defopEditor, gl = e.ui.glCanvas.getContext("webgl"), px = new Uint8Array(4);
  const q0 = [e.st.Q[0], e.st.Q[1]], r = 0.03 * e.st.view.diag, ms = [];
  for (let k = 0; k < n; k++) {
    const t0 = performance.now();
    e.st.Q[0] = q0[0] + r * Math.sin(k / 5); e.st.Q[1] = q0[1] + r * (1 - Math.cos(k / 5));
    e.evaluate();
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    ms.push(performance.now() - t0);
  }
  e.st.Q[0] = q0[0]; e.st.Q[1] = q0[1]; e.evaluate();
  return ms;
}"""


# the same for the 3D page: Q of handle 0 moved along a circle in the view plane, render, read one pixel back
SYNC_FRAMES_3D = """(n) => {
  const e = window.defopEditor, gl = e.scene.renderer.getContext(), px = new Uint8Array(4);
  const q0 = Array.from(e.st.Q.slice(0, 3)), r = 0.03 * e.scene.diag, ms = [];
  const m = e.camera.matrixWorld.elements; // camera x and y axes: the view plane
  for (let k = 0; k < n; k++) {
    const t0 = performance.now(), a = r * Math.sin(k / 5), b = r * (1 - Math.cos(k / 5));
    for (let c = 0; c < 3; c++) e.st.Q[c] = q0[c] + a * m[c] + b * m[4 + c];
    e.evaluate();
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    ms.push(performance.now() - t0);
  }
  for (let c = 0; c < 3; c++) e.st.Q[c] = q0[c];
  e.evaluate();
  return ms;
}"""


def in_page(page_path, steps, sync_frames=0, rest=None):
    """The standalone page: frame timestamps of the editor's rAF frames, and its own per-frame timings.

    With ``sync_frames``, also the times (ms) of that many frames with the GPU's work forced to finish; with
    ``rest`` (a MovableOp's page), movable handle 0's rest position is moved to that vertex first."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        page = chromium.new_page(viewport={"width": 1280, "height": 720})
        page.goto(page_path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        textured = page.evaluate("() => window.defopEditor.imageReady || false")
        if rest is not None and not page.evaluate(MOVE_REST, rest):
            raise RuntimeError(f"the page refused rest vertex {rest}")
        box = page.locator("canvas.defop-canvas").bounding_box()
        u, v = page.evaluate("() => window.defopEditor.handleScreen(0)")
        start = [box["x"] + u, box["y"] + v]
        page.evaluate(DRAG, [*start, 30, -20, 20])  # warm-up: JIT
        page.evaluate(
            "() => { const e = window.defopEditor; window.__stamps = []; e.st.evalMs = [];"
            " e.st.drawMs = []; e.onFrame = (t) => window.__stamps.push(t); }"
        )
        page.evaluate(DRAG, [*start, 160, -120, steps])
        res = page.evaluate(
            "() => ({stamps: window.__stamps, evalMs: window.defopEditor.st.evalMs,"
            " drawMs: window.defopEditor.st.drawMs})"
        )
        page.evaluate("() => { window.defopEditor.onFrame = null; }")
        sync = SYNC_FRAMES_3D if page.evaluate("() => !!window.defopEditor.scene") else SYNC_FRAMES
        res["syncMs"] = page.evaluate(sync, sync_frames) if sync_frames else []
        res["textured"] = textured
        page.screenshot(path=f"/tmp/defop_bench_{page_path.stem}.png")
        chromium.close()
    return res


def main(m=40, steps=200, ipympl=True):
    shape = dop.shapes.load("octopus")
    t0 = time.perf_counter()
    op, _ = dop.train(shape, basis="tps", m=m, progress=False)
    print(
        f"octopus: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles; {op} "
        f"({time.perf_counter() - t0:.0f} s to train or load from the cache)"
    )
    with tempfile.TemporaryDirectory() as tmp:
        page_path = export.to_html(op, Path(tmp) / "octopus.html", shape=shape)
        print(f"standalone page: {page_path.stat().st_size / 1e6:.1f} MB")
        res = in_page(page_path, steps)
    print(f"{steps}-step drag of one handle, one pointer event per animation frame, frames shown per second:")
    row = "  {:<34} median {:5.1f} fps, 5th percentile {:5.1f} fps ({} frames in {:.1f} s)"
    med, p5, n, span = rates(res["stamps"])
    print(row.format("in-page editor (this module):", med, p5, n, span))
    print(
        f"    per frame in the page: evaluation {np.median(res['evalMs']):.2f} ms, "
        f"draw submission {np.median(res['drawMs']):.2f} ms (medians)"
    )
    if ipympl:
        from bench_browser_ipympl import ipympl_drag

        print(row.format("ipympl editor (kernel round trip):", *rates(ipympl_drag(m, steps, DRAG))))
    print(f"target >= 55 fps median in the page: {'met' if med >= 55 else 'NOT met'}")


def horse(n_vertices=2000):
    """Notebook 13's horse: its picture, the shape (its handles and sampling discs) and the mesh → pixel map."""
    import skimage.data

    from defop.view import plot_peers, warp

    pad = 40
    mask = np.pad(~skimage.data.horse(), pad)
    handles_px = pad + np.array(
        [[64, 300], [124, 296], [259, 302], [281, 305], [372, 82], [28, 232], [180, 140]], float
    )
    regions = [{"kind": "disc", "radius": 0.06}] * 4 + [{"kind": "disc", "radius": 0.08}] * 2
    to_mesh, _ = warp.image_to_mesh_frame(mask)
    shape = dop.shapes.from_image(
        mask,
        handles=to_mesh(handles_px),
        moving=[True] * 6 + [False],
        regions=regions,
        n_vertices=n_vertices,
        name="horse",
    )
    _, to_pixels = warp.image_to_mesh_frame(mask, shape.mesh)
    return plot_peers.coat_picture(mask), shape, to_pixels


def main_image(m=40, n_vertices=2000, steps=200, rounds=3, sync_frames=60):
    """The picture editor beside the same page without the picture (see the module docstring)."""
    picture, shape, to_pixels = horse(n_vertices)
    op, _ = dop.train(shape, basis="tps", m=m, progress=False)
    print(
        f"horse: {shape.mesh.n_vertices} vertices, {len(shape.mesh.F)} triangles, {shape.n_moving} moving handles; "
        f"{op}; picture {picture.shape[1]} x {picture.shape[0]} px"
    )
    runs = {"plain mesh": [], "picture (texture)": []}
    with tempfile.TemporaryDirectory() as tmp:
        pages = {
            "plain mesh": export.to_html(op, Path(tmp) / "horse_plain.html", shape=shape),
            "picture (texture)": export.to_html(
                op, Path(tmp) / "horse_picture.html", shape=shape, image=picture, image_frame=to_pixels
            ),
        }
        for name, path in pages.items():
            print(f"  {name}: page {path.stat().st_size / 1e6:.2f} MB")
        for _ in range(rounds):  # alternate the two pages: the machine's load drifts
            for name, path in pages.items():
                runs[name].append(in_page(path, steps, sync_frames))
    assert all(r["textured"] for r in runs["picture (texture)"]), "the picture was not textured"
    print(
        f"{steps}-step drag, one pointer event per animation frame ({rounds} runs per page, alternating); "
        f"frame time forced to finish ({sync_frames} frames per run):"
    )
    sync = {}
    for name, rs in runs.items():
        fps = [rates(r["stamps"])[0] for r in rs]
        sync[name] = np.concatenate([r["syncMs"] for r in rs])
        ev, dr = (np.median(np.concatenate([r[k] for r in rs])) for k in ("evalMs", "drawMs"))
        print(
            f"  {name:<18} rAF median {np.median(fps):5.1f} fps (runs: {', '.join(f'{f:.0f}' for f in fps)}); "
            f"forced frame {np.median(sync[name]):5.2f} ms median, {np.percentile(sync[name], 90):5.2f} ms p90; "
            f"evaluation {ev:.2f} ms, draw submission {dr:.2f} ms"
        )
    ratio = np.median(sync["picture (texture)"]) / np.median(sync["plain mesh"])
    print(f"texture / plain forced frame time: {ratio:.2f}x")


def sized_operator_3d(shape, m, seed=0):
    """A TPS DefOp on ``shape`` of a trained operator's exact sizes (see the module docstring, ``--3d``).

    Centres: m configurations drawn in the shape's sampling regions (as training draws them); W: for each basis
    function an affine map of the rest positions with small random coefficients, so the page shows a smooth
    deformation. Prop. 2 and (8b) hold by construction of (★), whatever W is.
    """
    from defop.operator.defop import DefOp
    from defop.operator.handle_bases import make_basis
    from defop.scene.regions import as_region

    rng = np.random.default_rng(seed)
    P = shape.P_moving
    centers = np.stack([as_region(r).sample(rng, p, m, P, i) for i, (p, r) in enumerate(zip(P, shape.regions))], axis=1)
    diag = shape.mesh.bbox_diagonal
    basis = make_basis("tps", P, centers, scale=0.1 * diag)
    V = shape.mesh.V
    k = basis.size
    A = 0.02 * rng.standard_normal((k, 3, 3))
    t = 0.02 * diag * rng.standard_normal((k, 3))
    W = (np.einsum("vc,kdc->kvd", V - V.mean(axis=0), A) + t[:, None, :]).reshape(k, -1)
    W[0] = V.ravel()  # (★) reads W_F = W[1:] only; the rest pose comes from x
    meta = {"shape": shape.name, "energy": "sized", "n_samples": m}
    return DefOp(shape.mesh, shape.handles, shape.moving, basis, W, meta=meta, train_samples=centers)


def main_3d(m=40, rank=0, steps=200, rounds=3, trained=False, sync_frames=60):
    """Frames per second while dragging the 3D page of octopus_3d (see the module docstring)."""
    shape = dop.shapes.load("octopus_3d")
    t0 = time.perf_counter()
    if trained:
        op, _ = dop.train(shape, energy="sarap", basis="tps", m=m, progress=False)
        how = f"trained (S-ARAP, {time.perf_counter() - t0:.0f} s to train or load)"
    else:
        op = sized_operator_3d(shape, m)
        how = "of a trained operator's sizes, W synthetic (--trained trains it: about 90 s per sample)"
    if rank:
        op.compress(rank=rank)
    print(
        f"octopus_3d: {shape.mesh.n_vertices} vertices, {shape.mesh.n_faces} tetrahedra, "
        f"{len(shape.mesh.boundary_facets)} boundary triangles, {shape.n_moving} moving handles; {op}, {how}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        page_path = export.to_html(op, Path(tmp) / "octopus_3d.html", shape=shape)
        print(f"standalone 3D page: {page_path.stat().st_size / 1e6:.1f} MB")
        runs = [in_page(page_path, steps, sync_frames) for _ in range(rounds)]
    print(
        f"{steps}-step drag of one handle in the view plane, one pointer event per animation frame "
        f"({rounds} runs), frames shown per second:"
    )
    meds = []
    for r in runs:
        med, p5, n, span = rates(r["stamps"])
        meds.append(med)
        print(
            f"  3D page: median {med:5.1f} fps, 5th percentile {p5:5.1f} fps ({n} frames in {span:.1f} s); "
            f"evaluation {np.median(r['evalMs']):.2f} ms, normals + upload + render submission "
            f"{np.median(r['drawMs']):.2f} ms (medians)"
        )
    sync = np.concatenate([r["syncMs"] for r in runs])
    print(
        f"  frame time with the GPU's work forced to finish (evaluate, normals, upload, render, readPixels; "
        f"{len(sync)} frames): median {np.median(sync):.2f} ms, p90 {np.percentile(sync, 90):.2f} ms "
        f"(= {1000 / np.median(sync):.0f} fps without the display's 60 Hz cap)"
    )
    med = float(np.median(meds))
    print(f"target >= 55 fps median in the 3D page: {'met' if med >= 55 else 'NOT met'} ({med:.1f} fps)")


# before the drag: moving handle 0's rest position to the vertex of its placement region farthest from the nominal one
MOVE_REST = """(v) => window.defopEditor.setRest(0, v)"""


def main_movable(m=40, steps=200, rounds=2, sync_frames=60):
    """The page of a MovableOp with a rest handle moved, beside the fixed-P page (see the module docstring)."""
    from defop.scene.placement import placement_regions
    from defop.training.movable import train_movable

    shape = dop.shapes.load("octopus")
    pr = placement_regions(shape, [0, 3, 6], radius=0.05 * shape.mesh.bbox_diagonal)
    t0 = time.perf_counter()
    op0, _ = dop.train(shape, basis="tps", m=m, progress=False)
    opj, _ = train_movable(shape, pr, m=m, seed=0, progress=False)
    op0.compress(), opj.compress()
    print(
        f"octopus: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles, {pr.n_movable} movable "
        f"(regions of 5% of the diagonal, {[len(r) for r in pr.vertices]} vertices); fixed-P {op0} "
        f"(|Ψ| {op0.handle_basis.size}); movable {opj} (|Ψ| {opj.basis.size}, joint dimension "
        f"{opj.basis.dim}); {time.perf_counter() - t0:.0f} s to train or load"
    )
    side_by_side(shape, pr, {"fixed-P page": op0, "movable page, rest moved": opj}, steps, rounds, sync_frames)


def side_by_side(shape, pr, ops, steps, rounds, sync_frames):
    """The pages of the fixed-P and the movable operator ``ops`` (name: operator) dragged alternately, the movable
    one's rest handle 0 moved first to the vertex of its region farthest from the nominal one; prints their rAF
    rates, forced frame times, evaluation times and ratios."""
    V, region = shape.mesh.V, pr.vertices[0]
    rest = int(region[np.argmax(np.linalg.norm(V[region] - V[pr.nominal[0]], axis=1))])
    far = np.linalg.norm(V[rest] - V[pr.nominal[0]]) / shape.mesh.bbox_diagonal
    print(f"rest handle 0 moved to vertex {rest} ({far:.1%} of the diagonal) before the movable page's drags")
    runs = {name: [] for name in ops}
    with tempfile.TemporaryDirectory() as tmp:
        pages = {
            name: export.to_html(op, Path(tmp) / f"page{i}.html", shape=shape)
            for i, (name, op) in enumerate(ops.items())
        }
        for _ in range(rounds):  # alternate the two pages: the machine's load drifts
            for name, path in pages.items():
                runs[name].append(in_page(path, steps, sync_frames, rest=rest if "movable" in name else None))
        sizes = ", ".join(f"{path.stat().st_size / 1e6:.1f} MB" for path in pages.values())
    print(
        f"{steps}-step drag of handle 0, one pointer event per animation frame ({rounds} runs per page, "
        f"alternating); frame time forced to finish ({sync_frames} frames per run); pages {sizes}; load average "
        f"{os.getloadavg()[0]:.2f}:"
    )
    sync, ev = {}, {}
    for name, rs in runs.items():
        fps = [rates(r["stamps"])[0] for r in rs]
        sync[name] = np.concatenate([r["syncMs"] for r in rs])
        ev[name], dr = (np.median(np.concatenate([r[k] for r in rs])) for k in ("evalMs", "drawMs"))
        print(
            f"  {name:<26} rAF median {np.median(fps):5.1f} fps (runs: {', '.join(f'{f:.0f}' for f in fps)}); "
            f"forced frame {np.median(sync[name]):5.2f} ms median; evaluation {ev[name]:.2f} ms, draw "
            f"submission {dr:.2f} ms"
        )
    b, a = list(ops)
    print(
        f"movable / fixed-P: forced frame time {np.median(sync[a]) / np.median(sync[b]):.2f}x, "
        f"evaluation {ev[a] / ev[b]:.2f}x (load average {os.getloadavg()[0]:.2f})"
    )


def sized_movable_3d(shape, placement, m, seed=0):
    """A 3D MovableOp on ``shape`` of a trained one's sizes (:func:`defop.operator.movable.fit_movable` on m joint
    samples drawn as training draws them, X a smooth synthetic field): the page's work per frame depends on |Ψ|,
    the rank, the vertices and the bumps, not on the values (as :func:`sized_operator_3d`)."""
    from defop.operator.movable import fit_movable
    from defop.training.movable import sample_joint

    idx, Q = sample_joint(shape, placement, m, seed)
    V, diag = shape.mesh.V, shape.mesh.bbox_diagonal
    X = [
        V + 0.05 * diag * np.sin(V @ (q - V[placement.handles_at(i)[shape.moving]]).T / diag**2)[:, :3]
        for i, q in zip(idx, Q)
    ]
    meta = {"shape": shape.name, "energy": "sized"}
    return fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, np.stack(X), meta)


def smooth_factors(shape, size, rank, seed=0):
    """Factors (A (size − 1, rank), B (rank, 3 n_vertices)) in float32 of a compressed operator's sizes: B's rows
    smooth fields (sines of the rest positions along random directions), zero on the handles' columns."""
    rng = np.random.default_rng(seed)
    V, diag = shape.mesh.V, shape.mesh.bbox_diagonal
    B = 0.01 * diag * np.sin(np.einsum("vc,rcd->rvd", V, rng.standard_normal((rank, 3, 3)) * 6 / diag))
    B = B.reshape(rank, -1)
    B[:, (3 * shape.handles[:, None] + np.arange(3)).ravel()] = 0.0
    A = rng.standard_normal((size - 1, rank)) / np.sqrt(size)
    return A.astype(np.float32), B.astype(np.float32)


def main_movable_3d(m=200, rank=105, steps=200, rounds=2, sync_frames=60):
    """The 3D page of a MovableOp on octopus_3d (handle 0 movable within 5% of the diagonal, its rest moved to the
    farthest vertex of its region), beside the 3D fixed-P page of the same sizes (``--3d``), both with factors of
    ``rank`` (:func:`smooth_factors`; default the rank ``compress`` keeps for octopus_3d trained at m = 200): the
    ``--movable`` comparison in 3D."""
    from defop.scene.placement import placement_regions

    shape = dop.shapes.load("octopus_3d")
    pr = placement_regions(shape, [0], radius=0.05 * shape.mesh.bbox_diagonal)
    op0, opj = sized_operator_3d(shape, m), sized_movable_3d(shape, pr, m)
    op0.set_factors(smooth_factors(shape, op0.handle_basis.size, rank))
    opj.set_factors(smooth_factors(shape, opj.basis.size, rank))
    print(
        f"octopus_3d: {shape.mesh.n_vertices} vertices, {len(shape.mesh.boundary_facets)} boundary triangles, "
        f"{shape.n_moving} moving handles, 1 movable (region of 5% of the diagonal, {len(pr.vertices[0])} vertices, "
        f"patch of {len(pr.members[0])}); fixed-P {op0}; movable {opj} (|Ψ| {opj.basis.size}), both of a trained "
        "operator's sizes with synthetic factors"
    )
    ops = {"3D fixed-P page": op0, "3D movable page, rest moved": opj}
    side_by_side(shape, pr, ops, steps, rounds, sync_frames)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if "--3d" in sys.argv and "--movable" in sys.argv:
        main_movable_3d(*(int(a) for a in args[:2]))
    elif "--3d" in sys.argv:
        main_3d(
            *(int(a) for a in args[:2]),
            rounds=int(os.environ.get("DEFOP_BENCH_ROUNDS", 3)),
            trained="--trained" in sys.argv,
        )
    elif "--movable" in sys.argv:
        main_movable(*(int(a) for a in args[:1]))
    elif "--image" in sys.argv:
        main_image(*(int(a) for a in args[:2]))
    else:
        main(*(int(a) for a in args[:1]), ipympl="--no-ipympl" not in sys.argv)
