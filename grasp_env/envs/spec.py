"""The environments' keywords, one record each: one name, one unit, one default, one range.

Every grasp environment (the cube grasp, the gait, the general objects) reads its keywords
through these records, the training configs check a config's ``env_kwargs`` with them when it
is loaded (long before an environment is built), and docs/environments.md's table of accepted
inputs is checked against them by the tests. An environment keeps the checked values as
attributes of the same names (``env.unwrapped.k_max_ratio``; a batched vector env's
``template``), and the agents read them back from the environment, never from a config's dict.

**Units.** The mechanics of every environment are computed in units of the object's weight
w (forces in w, torques in w L), so a reward does not depend on the weight. ``k_max_ratio``
is k_max / w: the half-width of the box of the interaction scalars, |k_ij| <= k_max, in units
of w. :func:`~grasp_env.mechanics.solve_minimax` takes k_max in the unit of the grasp's forces
F_i: the environments pass ``k_max_ratio`` with forces in units of w, and the gait's mechanics
(forces in newtons) pass ``k_max_ratio * weight``: the same box either way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..mechanics.checks import real_number


@dataclass(frozen=True)
class Parameter:
    """One keyword: its name, unit (``""`` if none), default, accepted range and meaning.

    ``kind`` is ``"number"`` (a finite real number in the range), ``"range"`` (a (low, high)
    pair with low <= high, both in the range: the bounds of a uniform draw) or ``"flag"``
    (True or False; the range is unused). ``default`` is None where the environment's own
    default depends on the family (documented with it).
    """

    name: str
    unit: str
    default: Any
    low: float = 0.0
    high: float = 0.0
    open_low: bool = False
    open_high: bool = False
    kind: Literal["number", "range", "flag"] = "number"
    doc: str = ""

    @property
    def range(self) -> tuple[float, float]:
        """The closed or open bounds (low, high)."""
        return (self.low, self.high)

    def accepted(self) -> str:
        """The accepted values in words, e.g. ``"[0.001, 1000] w"``."""
        if self.kind == "flag":
            return "True or False"
        low = "(" if self.open_low else "["
        high = ")" if self.open_high else "]"
        bounds = f"{low}{self.low:g}, {self.high:g}{high}" + (f" {self.unit}" if self.unit else "")
        return f"a (low, high) pair within {bounds}" if self.kind == "range" else bounds

    def check(self, value: Any, name: str | None = None) -> Any:
        """``value`` checked (a float, a (low, high) pair of floats or a bool), or a
        ValueError naming ``name`` (default: the keyword) and the accepted values."""
        name = name or self.name
        if self.kind == "flag":
            if not isinstance(value, bool | np.bool_):
                raise ValueError(f"{name} must be True or False, got {value!r}")
            return bool(value)
        if self.kind == "number":
            return real_number(
                name, value, self.low, self.high, open_low=self.open_low, open_high=self.open_high
            )
        from .validation import check_range  # the pair's own rules (length, order)

        return check_range(name, value, self.low, self.high, open_low=self.open_low)


def _range_of(parameter: Parameter, name: str, default: tuple[float, float] | None) -> Parameter:
    """The (low, high) keyword ``name`` of uniform draws of ``parameter``."""
    return Parameter(
        name,
        parameter.unit,
        default,
        parameter.low,
        parameter.high,
        parameter.open_low,
        parameter.open_high,
        kind="range",
        doc=f"uniform range of the drawn {parameter.name}",
    )


K_MAX_RATIO = Parameter(
    "k_max_ratio",
    "w",
    2.0,
    1e-3,
    1e3,
    doc="k_max / w: an action a in [-1, 1] is the interaction scalar k = a k_max",
)
#: With ``physics="mujoco"``: a finger's force is at most |F_i| + (n - 1) k_max, which must stay
#: below the MuJoCo contact's ``grasp_env.physics.model.MAX_FORCE`` (150 w).
K_MAX_RATIO_MUJOCO = Parameter(
    "k_max_ratio", "w", 2.0, 1e-3, 40.0, doc="k_max / w of an environment checked in MuJoCo"
)
WEIGHT = Parameter("weight", "N", None, 1e-6, 1e6, doc="the object's weight w")
MU = Parameter("mu", "", None, 1e-3, 1e3, doc="Coulomb friction coefficient (0.057-89.94 deg)")
ALPHA = Parameter("alpha", "deg", None, -180.0, 180.0, doc="a pose's rotation about the axis")
ALPHA_STEP = Parameter(
    "alpha_step_deg", "deg", 1.0, 0.0, 360.0, open_low=True, doc="the trajectory's step"
)
MIN_EXPERT_MARGIN = Parameter(
    "min_expert_margin_deg",
    "deg",
    1.0,
    0.0,
    45.0,
    open_high=True,
    doc="the margin the expert keeps at every pose of a drawn scene",
)
CONTACT_OFFSET = Parameter(
    "contact_offset",
    "half-width",
    0.5,
    0.0,
    1.0,
    open_high=True,
    doc="largest offset of a drawn contact from its face centre",
)
CG_OFFSET_MAX = Parameter(
    "cg_offset_max",
    "half-width",
    0.2,
    0.0,
    1.0,
    open_high=True,
    doc="largest offset of a drawn centre of gravity, per axis",
)
EXTRA_FORCE_MAX = Parameter(
    "extra_force_max",
    "w",
    0.0,
    0.0,
    1.0,
    doc="bound of each component of a drawn extra load force",
)
EXTRA_TORQUE_MAX = Parameter(
    "extra_torque_max",
    "w L",
    0.0,
    0.0,
    1.0,
    doc="bound of each component of a drawn extra load torque",
)
CONE = Parameter(
    "cone_deg",
    "deg",
    None,
    0.0,
    180.0,
    open_low=True,
    open_high=True,
    doc="a finger's reach: the half-angle of its cone of approach directions",
)
TERMINATE_ON_SLIP = Parameter(
    "terminate_on_slip", "", True, kind="flag", doc="end the episode when a finger slips"
)
WEIGHT_DRAWS = _range_of(WEIGHT, "weight_range", (1.0, 10.0))
MU_DRAWS = _range_of(MU, "mu_range", (0.3, 1.0))
ALPHA_START_DRAWS = _range_of(ALPHA, "alpha_start_range_deg", (-30.0, -10.0))
ALPHA_END_DRAWS = _range_of(ALPHA, "alpha_end_range_deg", (10.0, 30.0))

#: The records by keyword: what a config's ``env_kwargs`` is checked with.
PARAMETERS: Mapping[str, Parameter] = {
    p.name: p
    for p in (
        K_MAX_RATIO,
        WEIGHT,
        MU,
        ALPHA_STEP,
        MIN_EXPERT_MARGIN,
        CONTACT_OFFSET,
        CG_OFFSET_MAX,
        EXTRA_FORCE_MAX,
        EXTRA_TORQUE_MAX,
        CONE,
        TERMINATE_ON_SLIP,
        WEIGHT_DRAWS,
        MU_DRAWS,
        ALPHA_START_DRAWS,
        ALPHA_END_DRAWS,
    )
}

#: The object family's defaults where they differ from the records' (the cube's): its draws
#: (envs/object_grasp/) are solved by the conic solver for five or more contacts, about 500
#: poses a second, so its turns are shorter and coarser (+-5 to 20 deg by 2.5 deg, up to 17
#: poses, where the cube's +-10 to 30 deg by 1 deg give up to 61) and its mu and contact
#: spread those that let a useful share of curved draws hold throughout.
OBJECT_DEFAULTS: Mapping[str, Any] = {
    "contact_offset": 0.6,
    "mu_range": (0.4, 1.0),
    "alpha_start_range_deg": (-20.0, -5.0),
    "alpha_end_range_deg": (5.0, 20.0),
    "alpha_step_deg": 2.5,
}
#: Keywords renamed in 0.2.0, each to its new name: ``cg_offset`` and the extra load's names
#: stand for a scene's vectors; a random env's largest draws are ``*_max``.
RENAMED: Mapping[str, str] = {
    "cg_offset": "cg_offset_max",
    "extra_force": "extra_force_max",
    "extra_torque": "extra_torque_max",
}


def check_keywords(env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """The keywords of a config's ``env_kwargs`` that have a record, checked (ValueError for a
    value outside its range, naming ``env_kwargs.<name>``); ``k_max_ratio`` with
    ``physics="mujoco"`` within :data:`K_MAX_RATIO_MUJOCO`'s range. The others (scenes, faces,
    physics, ...) are the environment's own to check when it is built."""
    checked = {}
    for name, value in env_kwargs.items():
        if name in RENAMED:
            raise ValueError(
                f"env_kwargs.{name} is now {RENAMED[name]} (the largest drawn; {name} names a"
                " scene's vector, a key of a scene option)"
            )
        parameter = PARAMETERS.get(name)
        if name == "k_max_ratio" and env_kwargs.get("physics") == "mujoco":
            parameter = K_MAX_RATIO_MUJOCO
        if parameter is not None:
            label = f"env_kwargs.{name}" + (
                " (with physics='mujoco')" if parameter is K_MAX_RATIO_MUJOCO else ""
            )
            checked[name] = parameter.check(value, label)
    return checked


__all__ = [
    "ALPHA",
    "ALPHA_END_DRAWS",
    "ALPHA_START_DRAWS",
    "ALPHA_STEP",
    "CG_OFFSET_MAX",
    "CONE",
    "CONTACT_OFFSET",
    "EXTRA_FORCE_MAX",
    "EXTRA_TORQUE_MAX",
    "K_MAX_RATIO",
    "K_MAX_RATIO_MUJOCO",
    "MIN_EXPERT_MARGIN",
    "MU",
    "MU_DRAWS",
    "OBJECT_DEFAULTS",
    "PARAMETERS",
    "RENAMED",
    "TERMINATE_ON_SLIP",
    "WEIGHT",
    "WEIGHT_DRAWS",
    "Parameter",
    "check_keywords",
]
