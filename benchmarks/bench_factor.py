"""Sparse factorisation libraries side by side on the solver's reduced Hessian (issue 15).

The Newton step of ``defop.variational.solver`` factorises the reduced (free-vertex) Hessian of the S-ARAP energy, an
SPD matrix with one dense 2×2 block per mesh edge and vertex. Its numeric factorisation is about 45% of
a cold solve on large meshes (issue 15), so this compares, on aleph-like meshes of 1k to 30k vertices:

* **qdldl** (today's solver: LDLᵀ, AMD ordering and symbolic analysis once, ``update`` = numeric only);
* **scipy splu** (SuperLU, the fallback in ``solve.py``: ordering + factorisation every time);
* **cholespy** (PyPI wheel, CHOLMOD's supernodal Cholesky bundled; its constructor analyses and factorises,
  there is no numeric-only refactorisation);
* **scikit-sparse** (CHOLMOD, ``cholesky_inplace`` = numeric only) when it is installed (the current
  release needs SuiteSparse 7; Debian 12 ships 5.12).

The matrix has the Hessian's exact sparsity pattern, kron(−L_cot + εI, [[2, 1], [1, 2]]) restricted to
the free vertices (SPD; a factorisation's cost depends on the pattern, not on the values), so the
benchmark does not depend on ``solve.py``'s internals. One BLAS thread (threadpoolctl); each time is
the median and best of 5; every solution's relative residual is printed.

Run: ``python benchmarks/bench_factor.py``.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from threadpoolctl import threadpool_limits

SIZES = (1000, 3000, 10000, 30000)


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
        from sksparse.cholmod import cholesky

        f = cholesky(K)

        def k():
            f.cholesky_inplace(K)
            return f(b)

        out["scikit-sparse cholmod (refactor + solve)"] = k
    except ImportError:
        pass
    return out


def main(sizes=SIZES):
    print("reduced S-ARAP Hessian pattern on aleph-like meshes; one BLAS thread; median / best of 5 (ms)")
    for size in sizes:
        K, n = reduced_hessian(size)
        b = np.random.default_rng(0).standard_normal(K.shape[0])
        print(f"\n{n} vertices: {K.shape[0]} unknowns, {K.nnz} nonzeros")
        base = None
        with threadpool_limits(limits=1):
            for name, f in candidates(K, b).items():
                med, best, x = timed(f)
                res = np.linalg.norm(K @ x - b) / np.linalg.norm(b)
                base = base or best
                print(
                    f"  {name:42s} {1e3 * med:9.1f} / {1e3 * best:9.1f}   {base / best:5.2f}x qdldl's speed   "
                    f"residual {res:.1e}"
                )


if __name__ == "__main__":
    main()
