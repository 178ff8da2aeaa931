"""Meshes, planar and tetrahedral, are identical on every CPU and BLAS build.

OpenBLAS picks its kernels per CPU and numpy dispatches some ufuncs (e.g. ``exp``) to AVX-512 code, so
anything on the way to Triangle that goes through them can round differently on another machine, and
Triangle plus the vertex-count loop turn 3e-16 into another mesh (the octopus had 3915/3911/3916
vertices under three kernels before). Each configuration runs in its own process, meshes every named
shape plus a polygon and an image shape, and prints a hash of V and F; all must agree byte for byte.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SCRIPT = """
import hashlib
import numpy as np
import defop as dop

def digest(mesh):
    return hashlib.sha256(mesh.V.tobytes() + mesh.F.tobytes()).hexdigest()[:20]

for name in dop.shapes.names():
    print(name, dop.shapes.load(name).mesh.n_vertices, digest(dop.shapes.load(name).mesh))
t = np.linspace(0, 2 * np.pi, 60, endpoint=False)
ring = dop.shapes.from_polygon(np.column_stack([np.cos(t), 0.6 * np.sin(t)]),
                               [0.25 * np.column_stack([np.cos(t), np.sin(t)])[::-1]],
                               handles=[[-0.7, 0], [0.7, 0]], n_vertices=600)
print("ring", ring.mesh.n_vertices, digest(ring.mesh))
yy, xx = np.mgrid[:200, :300]
star = np.hypot(xx - 150, yy - 100) < 70 + 20 * np.cos(5 * np.arctan2(yy - 100, xx - 150))
image = dop.shapes.from_image(star, n_vertices=800)
print("star_image", image.mesh.n_vertices, digest(image.mesh))
"""


SCRIPT_3D = """
import hashlib
import numpy as np
from defop.geometry.fields import capsule, ellipsoid, union
from defop.geometry.volumetric import mesher
from defop.geometry.volumetric import surface as surf
from defop.scene import models

def digest(mesh):
    return hashlib.sha256(mesh.V.tobytes() + mesh.F.tobytes()).hexdigest()[:20]

for name, n in (("bar_3d", 1500), ("plank_3d", 1000), ("octopus_3d", 3000), ("nut", 1500)):
    mesh = models.model(name).mesh(n)
    print(name, mesh.n_vertices, digest(mesh))
f = union(ellipsoid((0, 0, 0), (0.5, 0.4, 0.3)), capsule((0.3, 0, 0), (1.0, 0.2, 0.1), 0.15, 0.08))
bbox = [[-0.6, -0.5, -0.4], [1.2, 0.5, 0.4]]
h = mesher.grid_spacing(lambda P: f(P) > 0, bbox, 2500)
mesh = mesher.tet_mesh(lambda P: f(P) > 0, bbox, h, project=mesher.field_projector(f, h))
print("field", mesh.n_vertices, digest(mesh))
V, F = surf.read_surface(models.pyvista_example_path("sphere.ply"))
mesh = surf.surface_mesh(V, F, n_vertices=1500)
el, bary = mesh.locate(V)
print("sphere", mesh.n_vertices, digest(mesh), hashlib.sha256(bary.tobytes()).hexdigest()[:20])
"""


def _numpy_simd_off():
    """NPY_DISABLE_CPU_FEATURES value that turns off numpy's dispatched SIMD targets (AVX2/AVX-512 ...)."""
    import numpy as np

    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # numpy < 2
        from numpy.core._multiarray_umath import __cpu_dispatch__
    del np
    return " ".join(__cpu_dispatch__)


CONFIGS = {
    "default": {},
    "Haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "SkylakeX": {"OPENBLAS_CORETYPE": "SkylakeX"},
    "Sandybridge": {"OPENBLAS_CORETYPE": "Sandybridge"},
    "numpy baseline SIMD": {"NPY_DISABLE_CPU_FEATURES": _numpy_simd_off()},
}


def _run(extra, script=SCRIPT):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OPENBLAS_CORETYPE", "NPY_DISABLE"))}
    env.update(extra, OPENBLAS_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())


@pytest.mark.slow
def test_meshes_identical_under_every_blas_kernel_and_simd_target():
    results = {name: _run(extra) for name, extra in CONFIGS.items()}
    reference = results["default"]
    assert len(reference) == 9
    for name, got in results.items():
        differ = {k: (reference[k], v) for k, v in got.items() if v != reference[k]}
        assert not differ, f"{name}: meshes differ from the default run: {differ}"


@pytest.mark.slow
def test_tet_meshes_identical_under_every_blas_kernel_and_simd_target():
    """The Kuhn-cube meshes of the solids, of a field and of a closed surface (with its embedding), bit for bit."""
    results = {name: _run(extra, SCRIPT_3D) for name, extra in CONFIGS.items()}
    reference = results["default"]
    assert len(reference) == 6
    for name, got in results.items():
        differ = {k: (reference[k], v) for k, v in got.items() if v != reference[k]}
        assert not differ, f"{name}: tetrahedral meshes differ from the default run: {differ}"
