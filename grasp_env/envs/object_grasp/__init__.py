"""The object grasp family: hold any object (a box, cylinder, sphere or convex mesh) by 3 to 8
point contacts along a quasi-static turn; `grasp_env/ObjectGrasp-v0` (one scene, given by
keywords) and `grasp_env/ObjectGraspRandom-v0` (a new shape, size, contact count and load every
episode), observations and actions padded to a fixed contact count with a mask.

Modules by role, as the cube grasp family's: ``scenes`` (shapes, surface coordinates, explicit
and random scenes), ``episodes`` (the padded layout, everything precomputed at reset, random
episodes drawn ahead), ``kernels`` (the padded step), ``env`` (the single environments) and
``vector`` (the batched vector environments).
"""

from .env import ObjectGraspEnv, ObjectGraspRandomEnv
from .episodes import ObjectLayout
from .vector import ObjectGraspRandomVectorEnv, ObjectGraspVectorEnv

__all__ = [
    "ObjectGraspEnv",
    "ObjectGraspRandomEnv",
    "ObjectGraspRandomVectorEnv",
    "ObjectGraspVectorEnv",
    "ObjectLayout",
]
