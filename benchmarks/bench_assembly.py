"""Is numba worth it for the Hessian assembly (issue 15)? numpy (``ReducedHessian.assemble``) against a numba loop.

On aleph-like meshes of 3k, 10k and 30k vertices, one BLAS thread, median / best of 7: the assembly of the
PSD-projected S-ARAP Hessian into the fixed CSC pattern from the per-triangle eigensystems, (1) as the solver
does it (numpy: a batched 6×4·4×6 product per triangle and one ``bincount``), (2) as a numba loop over the
triangles that adds each element's kept upper-triangle entries straight into the CSC values. Beside them, one
qdldl numeric factorisation of the same matrix, the step each assembly feeds. numba is not a dependency of
defop: without it only the numpy and qdldl columns are printed. Run: ``python benchmarks/bench_assembly.py``.
"""

from __future__ import annotations

import time

import numpy as np

SIZES = (3000, 10000, 30000)


def _times(f, repeats=7):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(out)), 1e3 * float(np.min(out))


def _numba_kernel():
    try:
        import numba
    except ImportError:
        return None

    @numba.njit(cache=False)
    def assemble(W, lamA, slot, nnz):
        out = np.zeros(nnz)
        lam = np.empty(4)
        for t in range(W.shape[0]):
            for k in range(4):
                lam[k] = max(lamA[t, k], 0.0)
            for i in range(6):
                for j in range(6):
                    p = slot[t, i, j]
                    if p >= 0:
                        v = 0.0
                        for k in range(4):
                            v += W[t, i, k] * lam[k] * W[t, j, k]
                        out[p] += v
        return out

    return assemble


def one(n, kernel):
    """One size: the row of timings (ms) and the relative disagreement of the numba assembly."""
    import qdldl
    from threadpoolctl import threadpool_limits

    import defop as dop

    shape = dop.shapes.load("aleph", n_vertices=n)
    mesh = shape.mesh
    solver = dop.variational.Solver(mesh, shape.handles, "sarap")
    Q = dop.training.sampling.sample_shape(shape, 1, np.random.default_rng(0))[0]
    X = solver.solve(shape.targets(Q)).X  # a solved configuration: realistic eigensystems
    with threadpool_limits(limits=1):
        local = solver.grad_hess(X, 1e-5)[3]
        H = solver.hessian
        ref = H.assemble(local, True)
        np_ms = _times(lambda: H.assemble(local, True))
        K = H.matrix(ref, 1e-10)
        fac = qdldl.Solver(K, upper=True)
        qd_ms = _times(lambda: fac.update(K, upper=True))
        row = f"{mesh.n_vertices:6d} vertices: numpy {np_ms[0]:6.1f} / {np_ms[1]:6.1f}"
        if kernel is not None:
            slot = -np.ones(mesh.n_faces * 36, np.int64)
            slot[H._keep] = H._inv
            args = (*local, slot.reshape(-1, 6, 6), H._nnz)
            diff = np.abs(kernel(*args) - ref).max() / np.abs(ref).max()
            nb_ms = _times(lambda: kernel(*args))
            row += f"   numba {nb_ms[0]:6.1f} / {nb_ms[1]:6.1f} ({np_ms[1] / nb_ms[1]:.1f}x, agree to {diff:.1e})"
    return row + f"   qdldl factorisation {qd_ms[0]:6.1f} / {qd_ms[1]:6.1f}"


def main():
    kernel = _numba_kernel()
    print("S-ARAP Hessian assembly on aleph-like meshes; one BLAS thread; median / best of 7 (ms)")
    for n in SIZES:
        print(one(n, kernel), flush=True)


if __name__ == "__main__":
    main()
