"""Pure numpy mechanics of the grasp: no gymnasium, mujoco or torch here (docs/design.md, "Architecture")."""

from .forces import (
    Grasp,
    contact_pairs,
    equilibrating_forces,
    friction_angles,
    grasp,
    grasp_matrix,
    interaction_basis,
    load_wrench,
    n_pairs,
    net_forces,
    scene_grasp,
)
from .minimax import MinimaxResult, Status, solve_minimax
from .rotations import axis_angle_matrix, matrix_quaternion, quaternion_matrix
from .scene import (
    DEFAULT_MU,
    DEFAULT_WEIGHT,
    FACES,
    FOUR_FINGER_FACES,
    PAPER_FACES,
    Scene,
    face_point,
)
from .trajectory import PAPER_AXIS, PHI, START_ROTATION, Trajectory, pose_rotation

__all__ = [
    "DEFAULT_MU",
    "DEFAULT_WEIGHT",
    "FACES",
    "FOUR_FINGER_FACES",
    "PAPER_AXIS",
    "PAPER_FACES",
    "PHI",
    "START_ROTATION",
    "Grasp",
    "MinimaxResult",
    "Scene",
    "Status",
    "Trajectory",
    "axis_angle_matrix",
    "contact_pairs",
    "equilibrating_forces",
    "face_point",
    "friction_angles",
    "grasp",
    "grasp_matrix",
    "interaction_basis",
    "load_wrench",
    "matrix_quaternion",
    "n_pairs",
    "net_forces",
    "pose_rotation",
    "quaternion_matrix",
    "scene_grasp",
    "solve_minimax",
]
