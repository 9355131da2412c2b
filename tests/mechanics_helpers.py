"""Shared by the tests of the numpy mechanics core (tests/test_mechanics_*.py): hypothesis
strategies for numbers, contact offsets, scenes and pose angles.
"""

import math

from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_FACES,
    Scene,
)

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)


offset = st.floats(-0.35, 0.35)


@st.composite
def scenes(draw) -> Scene:
    faces = draw(st.sampled_from([PAPER_FACES, FOUR_FINGER_FACES]))
    return Scene.on_faces(
        faces,
        offsets=draw(arrays(float, (len(faces), 2), elements=offset)),
        weight=draw(st.floats(1, 20)),
        cg_offset=draw(arrays(float, 3, elements=st.floats(-0.12, 0.12))),
        extra_force=draw(arrays(float, 3, elements=st.floats(-2, 2))),
        extra_torque=draw(arrays(float, 3, elements=st.floats(-0.5, 0.5))),
    )


alphas = st.floats(-math.radians(15), math.radians(15))
