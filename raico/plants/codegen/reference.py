"""Drake's own dynamics of a plant at a state, the reference the generated code
(:mod:`raico.plants.codegen.derive`) and the tree kernels (:mod:`raico.plants.codegen.rbd`) are checked against."""

from __future__ import annotations

import numpy as np


class DrakeReference:
    """``M``, inverse dynamics and ``dID/d(q, v)`` (AutoDiffXd) of ``plant`` by Drake; ``ctx`` holds
    the last state evaluated (for further float queries: poses, centre of mass)."""

    def __init__(self, plant):
        from pydrake.autodiffutils import AutoDiffXd
        from pydrake.multibody.tree import MultibodyForces_

        self.plant, self.m = plant, plant.num_positions()
        self.ctx = plant.CreateDefaultContext()
        self.forces = MultibodyForces_[float](plant)
        self.plant_ad = plant.ToAutoDiffXd()
        self.ctx_ad = self.plant_ad.CreateDefaultContext()
        self.forces_ad = MultibodyForces_[AutoDiffXd](self.plant_ad)

    def evaluate(self, q: np.ndarray, v: np.ndarray, a: np.ndarray):
        """``(M (m, m), ID(q, v, a) (m,), ID(q, v, 0) = h (m,), dID(q, v, a)/d(q, v) (m, 2m))``."""
        from pydrake.autodiffutils import ExtractGradient, InitializeAutoDiff

        plant, ctx, m = self.plant, self.ctx, self.m
        plant.SetPositions(ctx, q)
        plant.SetVelocities(ctx, v)
        plant.CalcForceElementsContribution(ctx, self.forces)
        tau = plant.CalcInverseDynamics(ctx, a, self.forces)
        h = plant.CalcInverseDynamics(ctx, np.zeros(m), self.forces)
        M = plant.CalcMassMatrix(ctx)
        qv = InitializeAutoDiff(np.concatenate([q, v])).reshape(-1)
        self.plant_ad.SetPositions(self.ctx_ad, qv[:m])
        self.plant_ad.SetVelocities(self.ctx_ad, qv[m:])
        self.plant_ad.CalcForceElementsContribution(self.ctx_ad, self.forces_ad)
        D = ExtractGradient(self.plant_ad.CalcInverseDynamics(self.ctx_ad, a, self.forces_ad))
        return M, tau, h, D
