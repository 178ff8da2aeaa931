"""Sparse factorisation libraries side by side on the solver's reduced Hessian, on triangle and tet meshes.

The Newton step of ``defop.variational.solver`` factorises the reduced (free-vertex) Hessian of the S-ARAP energy, an
SPD matrix with one dense 2×2 block per mesh edge and vertex. Its numeric factorisation is about 45% of
a cold solve on large meshes (issue 15), so this compares, on aleph-like meshes of 1k to 30k vertices:

* **qdldl** (today's solver: LDLᵀ, AMD ordering and symbolic analysis once, ``update`` = numeric only);
* **scipy splu** (SuperLU, the fallback in ``solve.py``: ordering + factorisation every time);
* **cholespy** (PyPI wheel, CHOLMOD's supernodal Cholesky bundled; its constructor analyses and factorises,
  there is no numeric-only refactorisation);
* **scikit-sparse** (CHOLMOD, ``cholesky_inplace`` = numeric only) when it is installed (the current
  release needs SuiteSparse 7; Debian 12 ships 5.12);
* **pypardiso** (MKL PARDISO, supernodal; x86-64 only, Intel's licence) when it is installed: the symbolic analysis
  (phase 11) once, then numeric refactorisation (phase 22) and solve (phase 33), through pypardiso's low-level call.

``--dim 3`` uses tetrahedral patterns instead: a structured grid of cubes, each split into 6 tetrahedra
(Kuhn), with 3 unknowns per vertex and one dense 3×3 block per edge, the pattern of a volumetric Hessian, with
the vertices of one face pinned as handles. ``--threads N`` lets BLAS and MKL use N threads (default 1).

The matrix has the Hessian's exact sparsity pattern, kron(−L_cot + εI, [[2, 1], [1, 2]]) restricted to
the free vertices (SPD; a factorisation's cost depends on the pattern, not on the values), so the
benchmark does not depend on ``solve.py``'s internals. One BLAS thread (threadpoolctl); each time is
the median and best of 5; every solution's relative residual is printed.

``--real`` uses the solver's own reduced S-ARAP Hessians instead (issue 28 §1): for each catalogue model
(``aleph`` at 1k, 3k, 10k and 30k vertices; the tet models ``bar_3d``, ``nut`` and ``octopus_3d``), one sampled
handle configuration, the biharmonic start the solver takes, and the Hessian's values there (μ = 1e-5, projected:
the matrix a Newton step factorises). It compares the solver's two back ends through the solver's own classes
(qdldl ``update`` + solve; :class:`defop.variational.problem.PardisoLDL` numeric factorisation + solve with 1 and 2
MKL threads), prints each one's one-off analysis, and checks the inertia of the exact (indefinite) Hessian at the
verification's shift agrees. ``--solve`` adds one full verified S-ARAP solve of that sample with each back end.

Run: ``python benchmarks/bench_factor.py [--dim 3] [--threads 2] [--sizes 1000 4000]``,
``python benchmarks/bench_factor.py --real [--models bar_3d nut] [--solve]``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from threadpoolctl import threadpool_limits

SIZES = (1000, 3000, 10000, 30000)
SIZES_3D = (1000, 4000, 10000)


def kuhn_grid(n_vertices):
    """(V, T) of a structured tet grid of about ``n_vertices`` vertices, a 2:1:1 box, 6 tets per cube."""
    k = max(2, round((n_vertices / 4) ** (1 / 3)))
    nx, ny, nz = 2 * k, k, k
    idx = np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nx + 1, ny + 1, nz + 1)
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    V = g.reshape(-1, 3).astype(float)
    c = np.stack([idx[i : i + nx, j : j + ny, m : m + nz].ravel() for i in (0, 1) for j in (0, 1) for m in (0, 1)], 1)
    # the cube's corners c[:, 4i + 2j + m]; the 6 Kuhn tets share the diagonal 0 -> 7
    paths = [(0, 4, 6, 7), (0, 4, 5, 7), (0, 2, 6, 7), (0, 2, 3, 7), (0, 1, 5, 7), (0, 1, 3, 7)]
    T = np.concatenate([c[:, list(p)] for p in paths])
    return V, T


def tet_laplacian(V, T):
    """The graph Laplacian of the tets' edges (the cotangent Laplacian's pattern), (n, n)."""
    e = np.concatenate([T[:, [a, b]] for a in range(4) for b in range(a + 1, 4)])
    n = len(V)
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(float)
    return sp.diags(np.asarray(A.sum(1)).ravel()) - A


def reduced_hessian_3d(n_vertices):
    """An SPD matrix with a volumetric Hessian's pattern: 3 unknowns a vertex, the face x = 0 pinned."""
    V, T = kuhn_grid(n_vertices)
    n = len(V)
    L = tet_laplacian(V, T)
    block = np.array([[3.0, 1.0, 1.0], [1.0, 3.0, 1.0], [1.0, 1.0, 3.0]])
    K = sp.kron(L + 1e-8 * sp.identity(n), block).tocsc()
    free = np.flatnonzero(V[:, 0] > 0)
    dofs = (3 * free[:, None] + np.arange(3)).ravel()
    return sp.csc_matrix(K[dofs][:, dofs]), n


def reduced_hessian(n_vertices):
    """An SPD matrix with the pattern of the S-ARAP reduced Hessian on the aleph (free vertices only)."""
    import defop as dop

    shape = dop.shapes.load("aleph", n_vertices=n_vertices)
    L = -shape.mesh.cotmatrix
    n = shape.mesh.n_vertices
    K = sp.kron(L + 1e-8 * sp.identity(n), np.array([[2.0, 1.0], [1.0, 2.0]])).tocsc()
    free = np.setdiff1d(np.arange(n), shape.handles)
    dofs = (2 * free[:, None] + np.arange(2)).ravel()
    return sp.csc_matrix(K[dofs][:, dofs]), n


def timed(f, repeats=5):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), float(np.min(times)), out


def candidates(K, b):
    """name -> (numeric factorisation + solve callable, what it includes)."""
    out = {}
    upper = sp.triu(K, format="csc")
    try:
        import qdldl

        s = qdldl.Solver(upper, upper=True)

        def q():
            s.update(upper, upper=True)
            return s.solve(b)

        out["qdldl (update + solve)"] = q
    except ImportError:
        pass
    out["scipy splu (order + factor + solve)"] = lambda: sla.splu(
        K, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True)
    ).solve(b)
    try:
        import cholespy

        coo = K.tocoo()
        ii, jj = coo.row.astype(np.int32), coo.col.astype(np.int32)

        def c():
            x = np.zeros_like(b)
            cholespy.CholeskySolverD(K.shape[0], ii, jj, coo.data, cholespy.MatrixType.COO).solve(b, x)
            return x

        out["cholespy (analyse + factor + solve)"] = c
    except ImportError:
        pass
    try:
        import pypardiso

        ps = pypardiso.PyPardisoSolver(mtype=2)  # real symmetric positive definite: the upper triangle, CSR
        up_csr = sp.triu(K, format="csr")
        up_csr.sort_indices()
        rhs = b.reshape(-1, 1)
        t0 = time.perf_counter()
        ps.set_phase(11)
        ps._call_pardiso(up_csr, rhs)
        out["_pardiso_analysis_s"] = time.perf_counter() - t0

        def pd():
            ps.set_phase(22)
            ps._call_pardiso(up_csr, rhs)
            ps.set_phase(33)
            return np.asarray(ps._call_pardiso(up_csr, rhs)).ravel()

        out["pypardiso MKL (refactor + solve)"] = pd
    except ImportError:
        pass
    try:
        from sksparse.cholmod import cholesky

        f = cholesky(K)

        def k():
            f.cholesky_inplace(K)
            return f(b)

        out["scikit-sparse cholmod (refactor + solve)"] = k
    except ImportError:
        pass
    return out


REAL = (
    ("aleph", 1000),
    ("aleph", 3000),
    ("aleph", 10000),
    ("aleph", 30000),
    ("bar_3d", None),
    ("nut", None),
    ("octopus_3d", None),
)


def real_problem(name, n_vertices=None, seed=0):
    """(shape, targets, X): one sampled configuration of a catalogue model and the solver's biharmonic start."""
    import defop as dop
    from defop.training.sampling import sample_shape

    shape = dop.shapes.load(name, n_vertices=n_vertices) if n_vertices else dop.shapes.load(name)
    Q = sample_shape(shape, 1, np.random.default_rng(seed))[0]
    T = shape.targets(Q)
    return shape, T


def real_hessian(shape, T, backend):
    """The solver (on ``backend``), its projected S-ARAP Hessian values at the biharmonic start, the gradient."""
    from defop.variational import Solver

    solver = Solver(shape.mesh, shape.handles, "sarap", backend=backend)
    Tu = solver.targets_of(T)
    X = shape.mesh.V + solver.extend(Tu - shape.mesh.V[solver.handles])
    for _ in range(20):  # the start continuation takes: halve the move until no tet flips
        if not np.any(shape.mesh.flipped(X)):
            break
        X = 0.5 * (X + shape.mesh.V)
    _, g, data, _ = solver.grad_hess(X, 1e-5, project=True)
    _, _, exact, _ = solver.grad_hess(X, 0.0, project=False)
    return solver, data, exact, g[solver.free]


def _timed_backend(shape, T, backend, threads):
    """(analysis s, median s, best s, x, negative eigenvalues of the exact Hessian at INERTIA_SHIFT) of a back end."""
    from defop.variational.verify import INERTIA_SHIFT

    os.environ["DEFOP_MKL_THREADS"] = str(threads)
    solver, data, exact, b = real_hessian(shape, T, backend)
    t0 = time.perf_counter()
    solver.hessian.solve(data, b, 1e-10)  # the first call analyses (qdldl: AMD + etree; PARDISO: phase 11)
    first = time.perf_counter() - t0
    med, best, x = timed(lambda: solver.hessian.solve(data, b, 1e-10), 3)
    solver.hessian.solve(exact, b, INERTIA_SHIFT)
    K = solver.hessian.full(data)
    res = np.linalg.norm(K @ x - b) / np.linalg.norm(b)
    return first - best, med, best, res, solver.hessian.inertia(), len(b), len(data)


def real_solve(shape, T, backend):
    """One verified S-ARAP solve from the rest pose: (seconds, CPU seconds, result)."""
    from defop.variational import Solver

    solver = Solver(shape.mesh, shape.handles, "sarap", backend=backend)
    t0, c0 = time.perf_counter(), time.process_time()
    res = solver.solve(T)
    return time.perf_counter() - t0, time.process_time() - c0, res


def main_real(models=None, solve=False):
    from defop.variational import problem

    if not problem.HAVE_PARDISO:
        print("pypardiso is not installed (pip install -e '.[mkl]'): only qdldl is measured")
    else:  # load MKL (about 1 s, once per process) before any timing
        t0 = time.perf_counter()
        eye = sp.identity(2, format="csc")
        problem.PardisoLDL(eye).factor(eye)
        print(f"loading MKL and a first PARDISO call: {time.perf_counter() - t0:.2f} s (once per process)")
    todo = [m for m in REAL if models is None or m[0] in models or f"{m[0]}:{m[1]}" in models]
    print(
        f"real reduced S-ARAP Hessians (μ = 1e-5, projected) at one sampled configuration's biharmonic start; "
        f"median / best of 3 (ms); load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"{'model':>16s} {'verts':>6s} {'unknowns':>8s} {'nnz':>9s} | {'back end':18s} {'analysis':>9s} "
        f"{'factor+solve':>21s} {'speed-up':>8s} {'residual':>8s} {'neg.eig':>7s}"
    )
    runs = [("qdldl", 1)] + ([("pardiso", 1), ("pardiso", 2)] if problem.HAVE_PARDISO else [])
    for name, n in todo:
        shape, T = real_problem(name, n)
        base = None
        for backend, threads in runs:
            with threadpool_limits(limits=threads):
                an, med, best, res, neg, nf, nnz = _timed_backend(shape, T, backend, threads)
            base = base or best
            print(
                f"{name:>16s} {shape.mesh.n_vertices:6d} {nf:8d} {nnz:9d} | {backend + f' ({threads} thr)':18s} "
                f"{1e3 * an:9.1f} {1e3 * med:10.1f} / {1e3 * best:8.1f} {base / best:7.2f}x {res:8.1e} {neg!s:>7s}"
            )
        if solve:
            out = {}
            for backend, threads in runs[:2]:
                os.environ["DEFOP_MKL_THREADS"] = str(threads)
                with threadpool_limits(limits=threads):
                    wall, cpu, r = real_solve(shape, T, backend)
                out[backend] = r
                print(
                    f"{'':>16s} solve on {backend:8s}: {wall:8.1f} s wall, {cpu:8.1f} CPU s, {r.iterations:3d} "
                    f"iterations, E = {r.energy:.12g}, converged {r.converged}"
                )
            if len(out) == 2:
                a, b = out["qdldl"], out["pardiso"]
                dx = np.abs(a.X - b.X).max() / shape.mesh.bbox_diagonal
                print(f"{'':>16s} |ΔE|/E = {abs(a.energy - b.energy) / a.energy:.1e}, max |ΔX| / diagonal = {dx:.1e}")
    print(f"\nload average {os.getloadavg()[0]:.1f}")


def main(sizes=None, dim=2, threads=1):
    sizes = sizes or (SIZES if dim == 2 else SIZES_3D)
    where = "aleph-like meshes" if dim == 2 else "structured tet grids (6 Kuhn tets a cube)"
    load = os.getloadavg()[0]
    print(
        f"reduced S-ARAP Hessian pattern on {where}; {threads} BLAS/MKL thread(s); median / best of 5 (ms); "
        f"load average {load:.1f}"
    )
    for size in sizes:
        K, n = reduced_hessian(size) if dim == 2 else reduced_hessian_3d(size)
        b = np.random.default_rng(0).standard_normal(K.shape[0])
        print(f"\n{n} vertices: {K.shape[0]} unknowns, {K.nnz} nonzeros")
        base = None
        with threadpool_limits(limits=threads):
            found = candidates(K, b)
            analysis = found.pop("_pardiso_analysis_s", None)
            for name, f in found.items():
                repeats = 5 if K.shape[0] < 20000 or "qdldl" not in name else 3
                med, best, x = timed(f, repeats)
                res = np.linalg.norm(K @ x - b) / np.linalg.norm(b)
                base = base or best
                print(
                    f"  {name:42s} {1e3 * med:9.1f} / {1e3 * best:9.1f}   {base / best:5.2f}x qdldl's speed   "
                    f"residual {res:.1e}"
                )
            if analysis is not None:
                print(f"  (PARDISO's symbolic analysis, once per pattern: {1e3 * analysis:.1f} ms)")
    print(f"\nload average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--sizes", type=int, nargs="*")
    parser.add_argument("--real", action="store_true", help="the solver's own S-ARAP Hessians on catalogue models")
    parser.add_argument("--models", nargs="*", help="with --real: model names (or name:n_vertices for the aleph)")
    parser.add_argument("--solve", action="store_true", help="with --real: one full solve per back end too")
    args = parser.parse_args()
    if args.real:
        main_real(args.models, args.solve)
    else:
        main(args.sizes, args.dim, args.threads)
