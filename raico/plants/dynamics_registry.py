"""The dynamics models by name: one place to register, list and build them.

``make_dynamics(kind, robot, dt, params)`` builds a registered model; a model registers once
with :func:`register_dynamics` (name, builder, one-line description, whether it needs fitted
parameters). Built-ins: ``pseudo`` (backward Euler; ``pseudo-euler`` and ``pseudo-heun``, appendix C's
other two schemes) and ``analytic``. A new model (e.g. ``learned``, whose
builder takes the GP's fitted arrays as ``params``) is added by one ``register_dynamics`` call
at the end of this module; its own module must not import this one (no import cycle). Every
registered model is checked against finite differences by ``tests/plants/test_derivatives.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from raico.plants.dynamics import Dynamics, PseudoDynamics
from raico.plants.fast_analytic import make_fast_or_exact
from raico.plants.learned import build_learned, example_params

Builder = Callable[[Any, float, "Mapping[str, np.ndarray] | None"], Dynamics]


@dataclass(frozen=True)
class DynamicsSpec:
    """A registered model: ``builder(robot, dt, params) -> Dynamics`` (``dt`` in s)."""

    name: str
    builder: Builder
    description: str
    needs_params: bool = False
    example_params: Callable[[Any], Mapping[str, np.ndarray]] | None = None  # robot -> params (tests)


DYNAMICS: dict[str, DynamicsSpec] = {}


def register_dynamics(name: str, builder: Builder, description: str, needs_params: bool = False,
                      example_params: Callable[[Any], Mapping[str, np.ndarray]] | None = None) -> DynamicsSpec:
    """Register ``builder`` under ``name`` (unique); ``needs_params``: it requires ``params``, and
    ``example_params(robot)`` gives a small valid set (the derivative harness checks the model
    with it the moment it is registered)."""
    if not name or name in DYNAMICS:
        raise ValueError(f"dynamics name '{name}' is empty or already registered")
    if needs_params and example_params is None:
        raise ValueError(f"dynamics '{name}' needs params: register example_params too")
    spec = DynamicsSpec(name, builder, description, needs_params, example_params)
    DYNAMICS[name] = spec
    return spec


def dynamics_names() -> list[str]:
    """Registered model names, in registration order."""
    return list(DYNAMICS)


def make_dynamics(kind: str, robot, dt: float,
                  params: Mapping[str, Any] | None = None) -> Dynamics:
    """The model ``kind`` for ``robot`` with step ``dt`` (s); ``params`` only for models that
    need them (e.g. a learned model's fitted arrays). Bad input raises ``ValueError``."""
    spec = DYNAMICS.get(kind)
    if spec is None:
        raise ValueError(f"unknown dynamics '{kind}': choose one of {', '.join(DYNAMICS)}")
    if spec.needs_params and params is None:
        raise ValueError(f"dynamics '{kind}' needs params (fitted model parameters)")
    if not spec.needs_params and params is not None:
        raise ValueError(f"dynamics '{kind}' takes no params")
    return spec.builder(robot, dt, params)


def _build_pseudo(robot, dt: float, params: Mapping[str, np.ndarray] | None) -> Dynamics:
    return PseudoDynamics(robot.n_q, dt)


def _build_analytic(robot, dt: float, params: Mapping[str, np.ndarray] | None) -> Dynamics:
    return make_fast_or_exact(robot, dt)


register_dynamics("pseudo", _build_pseudo,
                  "thesis pseudo-dynamics: controls are joint accelerations, backward Euler")
register_dynamics("analytic", _build_analytic,
                  "Drake forward dynamics, semi-implicit Euler, controls are torques; generated "
                  "code where the plant compiles, else AutoDiffXd")
def _build_analytic_fd(robot, dt: float, params: Mapping[str, np.ndarray] | None) -> Dynamics:
    from raico.plants.numdiff import NumDiffDynamics

    return NumDiffDynamics(make_fast_or_exact(robot, dt))


register_dynamics("analytic-fd", _build_analytic_fd,
                  "the analytic model linearized by central differences of its step (the thesis's §3.4: 'the "
                  "linearizations are computed through finite differences'); an ablation, slow")
register_dynamics("learned", build_learned,
                  "GP mean of qddot = f(q, qdot, u) (a fit artifact's model), semi-implicit Euler, "
                  "controls are torques", needs_params=True, example_params=example_params)


def _pseudo_scheme(scheme: str) -> Builder:
    def build(robot, dt: float, params: Mapping[str, np.ndarray] | None) -> Dynamics:
        return PseudoDynamics(robot.n_q, dt, scheme)

    return build


# appendix C's other two pseudo-dynamics ("We compared all methods, and could not find any significant difference in
# terms of accuracy"): an ablation beside the backward Euler of "pseudo"
register_dynamics("pseudo-euler", _pseudo_scheme("euler"),
                  "pseudo-dynamics with Euler's method (appendix C.1: q' = q + dt qdot, B = [0; dt]); an ablation")
register_dynamics("pseudo-heun", _pseudo_scheme("heun"),
                  "pseudo-dynamics with Heun's method (appendix C.3: q' = q + dt/2 (qdot + qdot'), B = [dt^2/2; dt], "
                  "exact for an acceleration held over the step); an ablation")
