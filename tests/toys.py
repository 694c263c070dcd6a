"""Small nonlinear models shared by the solver and cost tests."""

import numpy as np


class PlanarArm:
    """End-effector position (m) of a planar arm with revolute joints: a nonlinear task map."""

    def __init__(self, lengths, name: str = "ee"):
        self.l = np.asarray(lengths, dtype=float)
        self.dim = 2
        self.name = name

    def values_and_jacobians(self, Q):
        c = np.cumsum(Q, axis=1)
        x, y = np.cos(c) * self.l, np.sin(c) * self.l
        phi = np.stack([x.sum(1), y.sum(1)], axis=1)
        Jx = -np.cumsum(y[:, ::-1], axis=1)[:, ::-1]
        Jy = np.cumsum(x[:, ::-1], axis=1)[:, ::-1]
        return phi, np.stack([Jx, Jy], axis=1)

    def value_and_jacobian(self, q):
        phi, J = self.values_and_jacobians(np.asarray(q)[None, :])
        return phi[0], J[0]
