"""The MuJoCo model of a scene: the box on a free joint and one force-driven fingertip per contact.

The settings are those that make MuJoCo's verdict agree with the analytic friction cone
(DESIGN.md §2): elliptic cones, a high impratio and stiff contacts so that a grasp inside the cone
does not creep, noslip iterations to enforce the cone exactly, 1 ms steps, and the dense
Jacobian (MuJoCo 4.0.0's sparse factorisation has a bug, fixed in 4.0.1).

Each fingertip is a small sphere on a body with three world-axis slide joints, gravity
compensated and driven by three force motors, so ``ctrl`` is exactly the commanded contact force
P_i (world frame). Each touches the box through one explicit contact pair with the scene's mu;
nothing else collides.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene, matrix_quaternion

#: Standard gravity, m/s^2: the object's mass is weight / G so that MuJoCo's gravity gives it
#: the scene's weight along world -z.
G = 9.81
#: Simulation step, seconds.
TIMESTEP = 1e-3
#: Fingertip sphere radius as a fraction of the box's smallest edge: small enough to be a point
#: contact, large enough to see.
TIP_RADIUS = 0.02
#: Fingertip mass as a fraction of the object's: light, so that a finger whose force leaves the
#: cone accelerates along the face quickly and the slip shows within the hold.
TIP_MASS = 0.02
#: The fingertips start this deep inside the face, as a fraction of the tip radius: at zero
#: distance MuJoCo makes no contact on the first step.
TIP_PENETRATION = 0.005
#: The object's rotational inertia is this many times a uniform box's. Statics do not depend on
#: it, and a large one slows the rotational instability of pure force control (DESIGN.md §2):
#: with fixed world-frame forces, a small rotation of the object changes the torque of every
#: contact force, which rotates it further.
INERTIA_SCALE = 100.0
#: Friction cone drawn per contact: its height as a fraction of the box's smallest edge.
CONE_HEIGHT = 0.3
#: Contact softness: stiff (time constant 5 ms, critically damped) and nearly hard impedance.
SOLREF = "0.005 1"
SOLIMP = "0.95 0.99 0.001 0.5 2"


def _vec(values: np.ndarray) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def cone_vertices(friction_limit: float, height: float, segments: int = 32) -> np.ndarray:
    """A friction cone of half-angle ``friction_limit``: apex at the origin, axis +z."""
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    radius = height * np.tan(friction_limit)
    rim = np.stack(
        [radius * np.cos(angles), radius * np.sin(angles), np.full(segments, height)], -1
    )
    return np.concatenate([np.zeros((1, 3)), rim])


def _z_to(direction: np.ndarray) -> np.ndarray:
    """A quaternion (w, x, y, z) rotating +z onto the unit vector ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, direction)
    s, c = np.linalg.norm(axis), float(np.dot(z, direction))
    if s < 1e-12:  # parallel or antiparallel: any perpendicular axis
        return np.array([1.0, 0.0, 0.0, 0.0]) if c > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    half = np.arctan2(s, c) / 2
    return np.concatenate([[np.cos(half)], np.sin(half) * axis / s])


def tip_radius(scene: Scene) -> float:
    return TIP_RADIUS * float(np.min(scene.size))


def check_rotation(rotation: ArrayLike) -> np.ndarray:
    """``rotation`` as a (3, 3) float array, or a ValueError saying what is wrong with it."""
    rotation = np.asarray(rotation, dtype=float)
    if rotation.shape != (3, 3):
        raise ValueError(f"rotation must be a (3, 3) matrix, got shape {rotation.shape}")
    if not np.all(np.isfinite(rotation)):
        raise ValueError("rotation must be finite (got NaN or inf)")
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError("rotation must be a proper rotation matrix (orthonormal, det = +1)")
    return rotation


def check_forces(forces: ArrayLike, n_contacts: int) -> np.ndarray:
    """``forces`` as an (n, 3) float array, or a ValueError saying what is wrong with them."""
    forces = np.asarray(forces, dtype=float)
    if forces.shape != (n_contacts, 3):
        raise ValueError(
            f"contact_forces must have shape ({n_contacts}, 3), one world-frame force per"
            f" finger, got {forces.shape}"
        )
    if not np.all(np.isfinite(forces)):
        raise ValueError("contact_forces must be finite (got NaN or inf)")
    return forces


def pose_qpos(scene: Scene, rotation: np.ndarray) -> np.ndarray:
    """qpos of the model of ``scene``: the object at ``rotation`` with its centre of gravity at
    the world origin, and each fingertip just inside its face at the contact point."""
    qpos = np.zeros(7 + 3 * scene.n_contacts)
    qpos[:3] = -rotation @ scene.cg_offset
    qpos[3:7] = matrix_quaternion(rotation)
    positions = scene.relative_contacts() @ rotation.T
    normals = scene.normals @ rotation.T
    standoff = tip_radius(scene) * (1 - TIP_PENETRATION)
    qpos[7:] = (positions - standoff * normals).ravel()
    return qpos


def build_mjcf(scene: Scene) -> str:
    """The MJCF text of ``scene``'s model (see the module docstring).

    The object body's frame is the box centre; its centre of gravity is the scene's
    ``cg_offset``. Joint positions (the object's pose, the fingertips' centres) are set per
    check, so one model serves every orientation. The friction cones are visual only
    (``contype = conaffinity = 0``, group 2) and open outwards from each contact, so the
    finger's push, drawn ending at the contact, lies inside its cone exactly when it holds.
    """
    size = np.asarray(scene.size, dtype=float)
    mass = scene.weight / G
    # Uniform-box inertia about the centre of gravity: any positive inertia would do for a
    # static check; this one keeps the dynamics plausible.
    inertia = (
        INERTIA_SCALE
        * mass
        / 12
        * np.array(
            [size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2]
        )
    )
    radius = tip_radius(scene)
    tip_mass = TIP_MASS * mass
    tip_inertia = 0.4 * tip_mass * radius**2
    cone_height = CONE_HEIGHT * float(np.min(size))
    extent = float(np.max(size))

    assets = [
        '<texture name="sky" type="skybox" builtin="gradient" rgb1="0.85 0.9 0.95"'
        ' rgb2="0.35 0.45 0.55" width="64" height="256"/>',
        f'<mesh name="cone" vertex="{_vec(cone_vertices(scene.friction_limit, cone_height))}"/>',
    ]
    cones, fingers, pairs, motors = [], [], [], []
    for i, (contact, normal) in enumerate(zip(scene.contacts, scene.normals, strict=True)):
        cones.append(
            f'<geom name="cone{i}" type="mesh" mesh="cone" pos="{_vec(contact)}"'
            f' quat="{_vec(_z_to(-normal))}" contype="0" conaffinity="0" group="2"'
            ' rgba="0.2 0.8 0.2 0.35"/>'
        )
        fingers.append(
            f'<body name="finger{i}" gravcomp="1">'
            + "".join(
                f'<joint name="finger{i}_{a}" type="slide" axis="{_vec(np.eye(3)[j])}"/>'
                for j, a in enumerate("xyz")
            )
            + f'<inertial pos="0 0 0" mass="{tip_mass:.17g}"'
            f' diaginertia="{_vec([tip_inertia] * 3)}"/>'
            f'<geom name="tip{i}" type="sphere" size="{radius:.17g}" rgba="0.85 0.55 0.2 1"'
            ' contype="0" conaffinity="0"/>'
            "</body>"
        )
        pairs.append(
            f'<pair name="contact{i}" geom1="tip{i}" geom2="box" condim="3"'
            f' friction="{scene.mu:.17g} {scene.mu:.17g} 0 0 0"'
            f' solref="{SOLREF}" solimp="{SOLIMP}"/>'
        )
        motors.extend(f'<motor name="finger{i}_{a}" joint="finger{i}_{a}"/>' for a in "xyz")

    return f"""<mujoco model="grasp">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{TIMESTEP}" gravity="0 0 {-G}" cone="elliptic" impratio="100"
          noslip_iterations="20" jacobian="dense"/>
  <visual>
    <global offwidth="1280" offheight="1280"/>
    <map znear="0.01" zfar="50"/>
    <headlight ambient="0.4 0.4 0.4" diffuse="0.6 0.6 0.6"/>
  </visual>
  <statistic center="0 0 0" extent="{extent:.17g}"/>
  <asset>
    {"".join(assets)}
  </asset>
  <worldbody>
    <light pos="{_vec([extent, -extent, 3 * extent])}" dir="{_vec([-1, 1, -3])}"
           diffuse="0.5 0.5 0.5"/>
    <body name="object">
      <freejoint name="object"/>
      <inertial pos="{_vec(scene.cg_offset)}" mass="{mass:.17g}" diaginertia="{_vec(inertia)}"/>
      <geom name="box" type="box" size="{_vec(size / 2)}" rgba="0.55 0.7 0.95 0.45"
            contype="0" conaffinity="0"/>
      {"".join(cones)}
    </body>
    {"".join(fingers)}
  </worldbody>
  <contact>
    {"".join(pairs)}
  </contact>
  <actuator>
    {"".join(motors)}
  </actuator>
</mujoco>
"""
