"""How a floating robot stands: the ``stand`` fact of a model file (``raico/plants/models/nao.toml``).

A robot executed ``floating`` (free on its soles, with contact: ``raico.plants.floating``) needs its feet, the
outline of a sole and this table: the sole plate's collision box, the ground contact's material, the
spheres that let a fallen robot lie on the floor, the joint PD gains of its actuators, the body whose
pose says whether it stands, and the whole-body stabilizer's gains (``raico.stages.execute.wbc``). Each key is
required; :func:`missing_for_floating` names what a spec lacks for a ``floating`` execution.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

CONTACT_KEYS = ("modulus", "dissipation", "friction", "bumper_stiffness")
GAIN_KEYS = ("kp", "kd")
STABILIZER_KEYS = ("kp", "kd", "kp_cog", "kd_cog", "kp_contact", "kd_contact", "kp_frame", "kd_frame")
KEYS = ("torso", "sole_box", "contact", "bumpers", "gains", "stabilizer")


class StandError(ValueError):
    """A ``stand`` table that does not say how the robot stands (the message names the key)."""


@dataclass(frozen=True)
class Stand:
    """The ``stand`` fact (module docstring), hashable: numbers as floats, tables as sorted pairs."""

    torso: str  # the body whose height and z axis tell a standing robot from a fallen one
    box_size: tuple[float, float, float]  # m, the sole plate's collision box
    box_center: tuple[float, float, float]  # m, in the sole frame (the box's bottom face at z = 0)
    contact: tuple[tuple[str, float], ...]  # CONTACT_KEYS: Pa, s/m, Coulomb friction, N/m
    bumpers: tuple[tuple[str, tuple[float, float, float], float], ...]  # (body, centre m, radius m)
    gains: tuple[tuple[str, float], ...]  # GAIN_KEYS: the actuators' PD, N m/rad and N m s/rad
    stabilizer: tuple[tuple[str, float], ...]  # STABILIZER_KEYS: 1/s^2 and 1/s

    def value(self, table: str, key: str) -> float:
        """One number of the ``contact``, ``gains`` or ``stabilizer`` table."""
        return dict(getattr(self, table))[key]

    def to_json(self) -> dict:
        return {"torso": self.torso, "sole_box": {"size": list(self.box_size), "center": list(self.box_center)},
                "contact": dict(self.contact), "bumpers": [[b, list(c), r] for b, c, r in self.bumpers],
                "gains": dict(self.gains), "stabilizer": dict(self.stabilizer)}


def _numbers(d: Any, keys: tuple[str, ...], what: str) -> tuple[tuple[str, float], ...]:
    if not isinstance(d, dict) or sorted(d) != sorted(keys) or \
            not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in d.values()):
        raise StandError(f"stand.{what}: a table of the numbers {', '.join(keys)}, got {d}")
    return tuple(sorted((str(k), float(v)) for k, v in d.items()))


def _vector(v: Any, what: str) -> tuple[float, float, float]:
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise StandError(f"stand.{what}: three numbers (m), got {v}")
    x, y, z = (float(a) for a in v)
    return x, y, z


def stand_from(d: Any) -> Stand:
    """The :class:`Stand` of a ``stand`` table (TOML or its JSON form); raises :class:`StandError`."""
    if not isinstance(d, dict):
        raise StandError("stand must be a table")
    missing = [k for k in KEYS if k not in d]
    extra = sorted(set(d) - set(KEYS))
    if missing or extra:
        raise StandError(f"stand: keys {', '.join(KEYS)}; missing {missing}, unknown {extra}")
    box = d["sole_box"]
    if not isinstance(box, dict) or sorted(box) != ["center", "size"]:
        raise StandError(f"stand.sole_box: {{size, center}}, got {box}")
    if not isinstance(d["bumpers"], list):
        raise StandError("stand.bumpers: a list of [body, [x, y, z], radius]")
    bumpers = []
    for b in d["bumpers"]:
        if not isinstance(b, (list, tuple)) or len(b) != 3 or not isinstance(b[0], str):
            raise StandError(f"stand.bumpers: [body, [x, y, z], radius], got {b}")
        bumpers.append((b[0], _vector(b[1], "bumpers"), float(b[2])))
    return Stand(torso=str(d["torso"]), box_size=_vector(box["size"], "sole_box.size"),
                 box_center=_vector(box["center"], "sole_box.center"),
                 contact=_numbers(d["contact"], CONTACT_KEYS, "contact"), bumpers=tuple(bumpers),
                 gains=_numbers(d["gains"], GAIN_KEYS, "gains"),
                 stabilizer=_numbers(d["stabilizer"], STABILIZER_KEYS, "stabilizer"))


def missing_for_floating(spec) -> list[str]:
    """The facts a ``floating`` execution needs that ``spec`` (a ``RobotSpec``) lacks: two ``feet`` (the
    stance sole first), a ``sole`` outline and the ``stand`` table."""
    out = []
    if len(spec.feet) != 2:
        out.append("feet (two soles, the stance one first)")
    if not spec.sole:
        out.append("sole (the outline of a sole in its frame)")
    if spec.stand is None:
        out.append("stand (" + ", ".join(KEYS) + ")")
    return out
