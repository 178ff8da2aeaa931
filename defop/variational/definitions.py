"""The names and parameters of the deformation energies, shared by the face (:mod:`.energies`) and the closed
forms in 2D (:mod:`.planar`) and 3D (:mod:`.volumetric`). See :mod:`.energies` for the formulas."""

from __future__ import annotations

ENERGIES = ("arap", "sarap", "isometric", "isometric_max", "isometric_exp")
BARRIER = {"arap": False, "sarap": True, "isometric": True, "isometric_max": True, "isometric_exp": True}
#: value of ψ at rotations (the rest pose), per energy, in 2D (3D: :data:`defop.variational.volumetric.REST_VALUE`)
REST_VALUE = {"arap": 0.0, "sarap": 0.0, "isometric": 4.0, "isometric_max": 0.0, "isometric_exp": 0.0}
#: the p of ``"isometric_max"``'s p-norm: ψ + 4^(2/p) lies between max(Σ, 1/σ)² and 4^(2/p) = 1.044 times it
MAX_POWER = 64.0
#: the s of ``"isometric_exp"``
EXP_SCALE = 0.25


def check_energy(energy):
    """Validate an energy name; raise ValueError listing the known ones."""
    if energy not in ENERGIES:
        raise ValueError(f"unknown energy {energy!r}; known energies: {', '.join(ENERGIES)}")
    return energy


def is_barrier(energy) -> bool:
    """Whether the energy is +inf on flipped triangles (S-ARAP and the isometric energies)."""
    return BARRIER[check_energy(energy)]
