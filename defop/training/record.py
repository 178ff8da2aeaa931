"""What a training did: the :class:`TrainingRecord` that :func:`defop.training.train` returns beside the operator."""

from __future__ import annotations

import dataclasses

import numpy as np

from . import multilevel as ml

__all__ = ["TrainingRecord"]


@dataclasses.dataclass
class TrainingRecord:
    """What training did.

    Attributes
    ----------
    samples : (m,n,d) numpy array
        The training configurations Q_k (rest pose excluded).
    X : (m,n_vertices,d) numpy array or None
        Their ground-truth deformations.
    converged : (m,) bool numpy array or None
    stage_times : dict of str -> float
        CPU seconds per stage (``bootstrap``, ``solve``, ``fit``, ``fold``; ``coarse``, ``fine`` for the multilevel
        policy; ``load``), summed over every process that worked on it (:class:`defop.training.solves.Stopwatch`).
    cache : str
        ``"operator"`` (loaded trained operator), ``"ground truth"`` (loaded samples, refitted) or ``"none"``.
    params : dict
    policy : str
        The policy that ran: ``"full"`` or ``"multilevel"`` (``params["policy"]`` is the one asked for).
    multilevel : dict
        ``"fallback"``: why one level ran where two were asked for ("" otherwise). After a multilevel training
        also, per sample: ``"rule"`` (the safeguard rule that fired, "" for none:
        :data:`defop.training.multilevel.RULES`), ``"iterations"`` (of the single fine run), ``"minima"`` (distinct
        verified coarse minima), ``"coarse_energy"`` (the coarse winner's), ``"cpu"`` (CPU seconds of the
        sample's fine stage: the single run, the safeguard's checks and any fallback, and the first sample of a
        handle set also building its solver; 0 where a checkpoint held it);
        and ``"coarse_vertices"``.
    wall_times : dict of str -> float
        Wall seconds per stage, beside ``stage_times``.
    work : float
        The work of the training's solves (:mod:`defop.training.work`: factor nonzeros over every factorisation and
        each solver's setup once), the same wherever the same back end runs the same solves; kept with the ground
        truth. NaN: not known (a truth cached without it or in other units, or a sample loaded from an interrupted
        run's checkpoint).
    work_units : dict
        The units of ``work`` (:func:`defop.training.work.units`: back end, re-use, constants, rule version).
    """

    samples: np.ndarray
    X: np.ndarray | None
    converged: np.ndarray | None
    stage_times: dict
    cache: str
    params: dict
    policy: str = "full"
    multilevel: dict = dataclasses.field(default_factory=dict)
    wall_times: dict = dataclasses.field(default_factory=dict)
    work: float = float("nan")
    work_units: dict = dataclasses.field(default_factory=dict)

    @property
    def safeguard(self) -> dict:
        """How often each safeguard rule fired (rule -> count; empty unless the multilevel policy ran)."""
        rules = self.multilevel.get("rule") or []
        return {r: rules.count(r) for r in ml.RULES if r in rules}

    @property
    def total_time(self) -> float:
        return float(sum(self.stage_times.values()))
