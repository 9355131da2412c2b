"""The MuJoCo model of a scene: the box on a free joint and one force-driven fingertip per contact.

**Units.** The statics are scale-free (forces in units of the weight w, lengths in units of the
box's largest edge L; docs/design.md §1), so the model is the scene scaled to a 1 N box of
largest edge 1: the object's mass is 1 / G, every force is divided by w and every length by L.
Any accepted weight or size then gives the same well-conditioned model (a 1e-9 N weight would
otherwise give MuJoCo masses below its mjMINVAL). For L = 1 m the dynamics are the real ones; for
another L they are the real ones with time scaled by sqrt(L), which leaves the quasi-static
verdict unchanged.

**Frame.** The model's world is the *hand's* frame, which turns with the object along a
trajectory (docs/physics.md): the object rests at the identity orientation with its centre of
gravity at the origin, and the load (the weight and any extra wrench, turned into the object's
frame) is an applied force at its centre of gravity (``xfrc_applied``), not MuJoCo's gravity.
Gravity is zero, so the fingertips need no gravity compensation.

**Contacts.** The settings are those that make MuJoCo's verdict agree with the analytic friction
cone (docs/physics.md): elliptic cones, a high impratio and stiff contacts so that a grasp inside
the cone does not creep, noslip iterations to enforce the cone exactly, and the dense Jacobian
(MuJoCo 4.0.0's sparse factorisation has a bug, fixed in 4.0.1). Each fingertip is a small sphere
on a body with three slide joints, driven by three force motors, so ``ctrl`` is exactly the
commanded contact force P_i. Each touches the box through one explicit contact pair with the
scene's mu; nothing else collides.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Box, Scene, matrix_quaternion
from grasp_env.mechanics.checks import real_array
from grasp_env.mechanics.rotations import check_rotations as check_rotations  # re-exported

#: Standard gravity, m/s^2: the object's mass is 1 / G, so that a 1 N load accelerates it as
#: the real weight accelerates the real box.
G = 9.81
#: Fingertip sphere radius as a fraction of the box's smallest edge: small enough to be a point
#: contact, large enough to see.
TIP_RADIUS = 0.02
#: Fingertip mass as a fraction of the object's: light, so that a finger whose force leaves the
#: cone accelerates along the face quickly and the slip shows within the hold.
TIP_MASS = 1e-3
#: The fingertips start this deep inside the face, as a fraction of the tip radius: at zero
#: distance MuJoCo makes no contact on the first step.
TIP_PENETRATION = 1e-3
#: A finger out of contact (released, or lifted in a gait) is parked this far off its face, in
#: tip radii: out of reach of the box.
PARK_DISTANCE = 3.0
#: The object's rotational inertia is this many times a uniform box's. Statics do not depend on
#: it, and a large one slows the rotational instability of pure force control (docs/physics.md):
#: with fixed forces, a small rotation of the object changes the torque of every contact force,
#: which rotates it further.
INERTIA_SCALE = 1e4
#: The same for a flat-faced object beyond the cube's setting (a convex mesh, or a box held by
#: 5 to 8 contacts): squeezes of five or six fingers of up to 9 w turn such an object past the
#: 0.1 deg rotation threshold over a 15-pose run at 1e4 (2 of 320 grips inside their cones in
#: the shapes' study); at 1e5 none of 440 did. Boxes with 3 or 4 contacts keep
#: :data:`INERTIA_SCALE`, their results the same bit for bit, and so do the curved shapes,
#: whose rolling friction holds them (at 1e5 one six-finger can grip 1 deg inside slid).
FLAT_INERTIA_SCALE = 1e5
#: Friction cone drawn per contact: the length of its slant side as a fraction of the box's
#: smallest edge. A fixed slant keeps the cone finite for any mu (a fixed height would not).
CONE_SLANT = 0.35
#: The drawn cone's half-angle is atan(mu) clamped to this range, degrees: a thinner cone has no
#: volume for MuJoCo's mesh compiler (and would not show), a wider one is a flat disc.
CONE_ANGLE_RANGE_DEG = (0.5, 89.5)
#: The largest finger force, in units of w, that the soft contact below carries faithfully: its
#: penetration grows with the force, and a tip pressed harder sinks through the face (measured
#: with the equal-k grip at a 55 deg margin: 1e-6 L of slide at 208 w, 4e4 L at 260 w).
MAX_FORCE = 150.0
#: Contact softness: stiff (time constant 5 ms, critically damped) and nearly hard impedance.
SOLREF = "0.005 1"
SOLIMP = "0.95 0.99 0.001 0.5 2"
#: The thinnest box the model checks faithfully: its smallest edge over its largest. The tips
#: scale with the smallest edge (TIP_RADIUS), the contact's impedance width (SOLIMP) and the
#: tips' mass do not. Measured with the expert's grip at mu = 1 on random contacts, thin along
#: each axis: 0.01 gave false slips (2 of 45 poses, 1 of 8 trajectories), 0.005 4 of 12 poses,
#: 0.02 to 0.05 none (217 poses, 32 trajectories); below about 1e-4 MuJoCo refuses the tips'
#: inertia. The limit keeps a factor 2.5 from the thinnest clean ratio.
MIN_ASPECT = 0.05
#: Torsional and rolling friction of a fingertip on a curved object (a cylinder or a sphere),
#: as a length in tip radii: 0.3 tip radii is 0.40 mm on the can (tip radius 1.32 mm). With
#: fixed world-frame finger forces a curved object *rolls* under its fingertips (a sphere
#: turned about its centre keeps every normal line through it: no stiffness at all), so with
#: condim 3 every stable grasp falls; condim 6 with some torsional and rolling friction makes
#: MuJoCo agree with the analytic verdict (docs/physics.md, "Curved objects"). Its price: the
#: rolling friction holds a torque error of up to this length times the normal forces. Measured
#: on 80 can trajectories (the contacts' lever arms restored, :func:`contact_shift`): 0.75 tip
#: radii (1 mm) held 6 of 40 grips whose torque was off by 0.03 N m (squeezing grips of 4 to
#: 6 fingers), 0.1 let 5 of 40 expert grips inside their cones roll loose, 0.3 did neither.
SPIN_FRICTION = 0.3
#: The shapes whose contact pairs get torsional and rolling friction (condim 6): the curved
#: ones. A box and a convex mesh have flat faces and keep the cube's condim 3.
CURVED = ("cylinder", "sphere")
#: On a curved object a touching tip's contact has its torsional and rolling friction
#: (condim 6) only at the steps where its commanded normal force is at least this share of the
#: grip's largest one; below it the pair is at condim 3 (:func:`rolling_contacts`). The tips
#: cannot turn, so every rolling row of a grip has the object's inverse inertia, and MuJoCo's
#: solver shares the torque that holds the object's slight roll among the rolling contacts
#: without regard to their normal forces; its elliptic cone takes each contact's share r from
#: the budget its sliding friction has, (f_t / mu N)^2 + (r / s N)^2 <= 1 (s the spin
#: length). A contact being released keeps its share while N falls, and loses its sliding
#: budget to it: traced on a squat cylinder's grip 2 deg inside (docs/physics.md), a finger
#: unloaded to 0.0025 w (the grip's largest 4.7 w) held r = 0.53 s N and crept at
#: 1.35e-5 L/s; the grip's other contacts held r = 0.017 s N at the median. Measured with
#: every touching contact rolling, on 36 expert grips of the shapes' study (cylinders, cans,
#: spheres; 3, 4 and 6 fingers) and that grip: contacts at 2% to 10% of the largest force had
#: r / s N of 0.016 to 0.09 at the 99th percentile (0.44 at most, on the traced grip, whose
#: cost, 1 - sqrt(1 - r^2 / s^2 N^2), is 10% of the sliding budget), those below 1% up to
#: 4.9. The largest contact always rolls, and so does every other above the share: they hold
#: the roll. 0.2 gave the same agreement on the study's seed 0 (docs/physics.md).
ROLLING_SHARE = 0.02
#: On a flat-faced object (a box or a convex mesh) each fingertip touches the half-space of its
#: own face (a box geom this many L deep and twice as wide, whose outer side is the face's
#: plane), not the object's geom: the soft contact sinks a tip about 2.5e-3 L per w deep
#: (:func:`contact_shift`), and near an edge that depth reaches past the neighbouring face,
#: which MuJoCo's collision then takes for the nearest (the tip's normal flips and it slides
#: through: a six-finger mesh grip 0.1 deg inside, a 6.7 w tip 0.0067 L from the next face's
#: plane and 0.017 L deep, fell at the settle's end; a six-finger grip on a 0.05 x 0.05 x
#: 0.39 m stick, a 7.6 w tip 0.019 L deep 0.014 L from an edge, fell mid-run). The analytic
#: contact is a point on its face, its normal fixed.
FACE_DEPTH = 1.0


def _vec(values: ArrayLike) -> str:
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def length_unit(scene: Scene) -> float:
    """L, the model's unit of length: the box's largest edge."""
    return float(np.max(scene.size))


def model_size(scene: Scene) -> np.ndarray:
    """The box's edge lengths in the model, (3,): the largest is 1."""
    return np.asarray(scene.size, dtype=float) / length_unit(scene)


def is_curved(scene: Scene) -> bool:
    """Whether the scene's object is curved (:data:`CURVED`): its contacts get condim 6."""
    return scene.shape.kind in CURVED


def contact_friction(scene: Scene) -> tuple[int, str]:
    """The contact pairs' ``condim`` and ``friction`` (sliding, sliding, torsional, rolling,
    rolling; model units): the scene's mu and nothing else on flat faces (condim 3); on a
    curved object (:func:`is_curved`) also :data:`SPIN_FRICTION` tip radii of torsional and
    rolling friction (condim 6)."""
    mu = f"{scene.mu:.17g} {scene.mu:.17g}"
    if not is_curved(scene):
        return 3, f"{mu} 0 0 0"
    spin = f"{SPIN_FRICTION * tip_radius(scene):.17g}"
    return 6, f"{mu} {spin} {spin} {spin}"


def rolling_contacts(normal: np.ndarray, touching: np.ndarray) -> np.ndarray:
    """Which touching contacts of a curved object roll (condim 6) at each step, (..., n):
    those whose commanded normal force ``normal`` (..., n, units of w) is at least
    :data:`ROLLING_SHARE` x the largest of the ``touching`` (..., n) contacts' at that step;
    the others (and those that do not touch) are at condim 3. The rule and its reason are
    :data:`ROLLING_SHARE`'s."""
    loaded = np.where(touching, normal, 0.0)
    largest = loaded.max(axis=-1, keepdims=True)
    return touching & (loaded > 0.0) & (loaded >= ROLLING_SHARE * largest)


def contact_shift(scene: Scene, inverse_inertia: float) -> float:
    """How far inside the object MuJoCo's contact point lies, per unit of normal force (model
    units: L per w), for a contact of inverse inertia A (MuJoCo's ``efc_diagApprox``).

    MuJoCo puts a contact midway through the penetration d, so d / 2 inside the surface along
    the inward normal nu_i, where the analytic contact c_i is on it; a finger force's tangential
    part then turns the object by (d / 2) nu_i x P_i more than the analytic grasp says. The
    soft contact (:data:`SOLREF`, :data:`SOLIMP`) holds a tip pushing with N at rest where its
    stiffness K I d equals the regulariser's R N, R = (1 - I) / I A: d = (1 - I) A N / (I^2 K),
    with K = 1 / (dmax^2 timeconst^2 dampratio^2) and I = dmax once d passes the impedance's
    width (0.001 L, about 0.4 w). About 2.5e-3 L per w, so a grip's lever arms are off by
    about 1e-2 L, and the torque by a few hundredths of w L: on a curved object the rolling
    friction takes it up and eats the sliding friction's budget (MuJoCo's elliptic cone shares
    it), making false slips near the cone's edge; on a flat one nothing resists it and it
    turns the object (a three-finger box grip 0.1 deg inside turned 0.118 deg, past the
    0.1 deg threshold, over a 15-pose run; 0.0001 deg restored). The controls take it back
    off the load on every shape (``batch._controls``): the returned d / (2 N)."""
    del scene  # the same soft contact for every scene (the shapes differ in A only)
    timeconst, dampratio = (float(v) for v in SOLREF.split())
    dmax = float(SOLIMP.split()[1])
    stiffness = 1.0 / (dmax**2 * timeconst**2 * dampratio**2)
    return 0.5 * (1.0 - dmax) * inverse_inertia / (dmax**2 * stiffness)


def object_geom(scene: Scene) -> tuple[str, str]:
    """The object's geom (named ``"box"`` for a box, else ``"object"``) and the ``<mesh>``
    asset it needs ("" for MuJoCo's primitives), in the model's units: MuJoCo's own box,
    cylinder, sphere or mesh from the shape's :meth:`~grasp_env.mechanics.objects.Shape.mujoco_geom`
    and :meth:`~grasp_env.mechanics.objects.Shape.mujoco_mesh`, every length divided by L."""
    style = 'rgba="0.55 0.7 0.95 0.45" contype="0" conaffinity="0"'
    if isinstance(scene.shape, Box):  # the cube's model, character for character
        return f'<geom name="box" type="box" size="{_vec(model_size(scene) / 2)}" {style}/>', ""
    geom = scene.shape.mujoco_geom()
    mesh = scene.shape.mujoco_mesh()
    scale = 1.0 / length_unit(scene)
    if mesh is None:
        size = np.array(geom["size"].split(), dtype=float) * scale
        return f'<geom name="object" type="{geom["type"]}" size="{_vec(size)}" {style}/>', ""
    vertices = np.array(mesh["vertex"].split(), dtype=float) * scale
    asset = f'<mesh name="{mesh["name"]}" vertex="{_vec(vertices)}"/>'
    return f'<geom name="object" type="mesh" mesh="{geom["mesh"]}" {style}/>', asset


def seam_geom(scene: Scene) -> str:
    """A cylinder's *seam*, for pictures only: a thin dark stripe down its side at azimuth 0
    (visual, group 2, no collision), so that its turn about its axis shows; "" for other
    shapes (a box's or a mesh's turn shows by itself)."""
    if scene.shape.kind != "cylinder":
        return ""
    scale = 1.0 / length_unit(scene)
    radius, height = scene.shape.radius * scale, scene.shape.height * scale
    half = [0.01 * radius, 0.08 * radius, 0.45 * height]
    return (
        f'<geom name="seam" type="box" pos="{_vec([radius, 0.0, 0.0])}" size="{_vec(half)}"'
        ' rgba="0.55 0.05 0.05 1" contype="0" conaffinity="0" group="2"/>'
    )


def object_geom_name(scene: Scene) -> str:
    """The name of the object's geom in the model (see :func:`object_geom`)."""
    return "box" if isinstance(scene.shape, Box) else "object"


def touches_faces(scene: Scene) -> bool:
    """Whether the fingertips touch their faces' half-spaces (:func:`face_geoms`) rather than
    the object's geom: on a flat-faced object (a box, the cube's included, or a convex
    mesh)."""
    return scene.shape.kind in ("box", "convex mesh")


def face_geoms(scene: Scene) -> str:
    """On a flat-faced object (:func:`touches_faces`), each contact's face as a half-space: a box
    geom ``face{i}`` on the object, :data:`FACE_DEPTH` L deep and 2 x :data:`FACE_DEPTH` L
    wide, whose outer side lies in the face's plane through the contact (collision through
    its contact pair only, invisible); "" otherwise."""
    if not touches_faces(scene):
        return ""
    half = _vec([FACE_DEPTH, FACE_DEPTH, FACE_DEPTH / 2])
    return "".join(
        f'<geom name="face{i}" type="box" size="{half}"'
        f' pos="{_vec(contact + 0.5 * FACE_DEPTH * normal)}" quat="{_vec(_z_to(normal))}"'
        ' contype="0" conaffinity="0" group="3" rgba="0 0 0 0"/>'
        for i, (contact, normal) in enumerate(
            zip(model_contacts(scene), scene.normals, strict=True)
        )
    )


def inertia_scale(scene: Scene) -> float:
    """The object's rotational inertia over a uniform box's (its bounding box):
    :data:`FLAT_INERTIA_SCALE` for a convex mesh or a box with more than 4 contacts, else
    :data:`INERTIA_SCALE`."""
    beyond = isinstance(scene.shape, Box) and scene.n_contacts > 4
    flat = not is_curved(scene) and (beyond or not isinstance(scene.shape, Box))
    return FLAT_INERTIA_SCALE if flat else INERTIA_SCALE


def check_aspect(scene: Scene) -> None:
    """A ValueError naming the scene's size if its box is thinner than :data:`MIN_ASPECT`."""
    ratio = float(np.min(model_size(scene)))
    if ratio < MIN_ASPECT:
        raise ValueError(
            f"the MuJoCo model checks boxes whose smallest edge is at least {MIN_ASPECT:g} x"
            f" their largest, got size {np.ravel(scene.size).tolist()} (ratio {ratio:.3g}):"
            " thinner, its fingertips make false slips (docs/physics.md)"
        )


def tip_radius(scene: Scene) -> float:
    """The fingertip radius in the model's units."""
    return TIP_RADIUS * float(np.min(model_size(scene)))


def model_contacts(scene: Scene) -> np.ndarray:
    """The contact points relative to the box centre in the model's units, (n, 3)."""
    return np.asarray(scene.contacts) / length_unit(scene)


def model_cg(scene: Scene) -> np.ndarray:
    """The centre of gravity relative to the box centre in the model's units, (3,)."""
    return np.asarray(scene.cg_offset) / length_unit(scene)


def cone_vertices(friction_limit: float, slant: float, segments: int = 32) -> np.ndarray:
    """A friction cone of half-angle ``friction_limit`` (clamped to
    :data:`CONE_ANGLE_RANGE_DEG`) and slant side ``slant``: apex at the origin, axis +z."""
    low, high = np.radians(CONE_ANGLE_RANGE_DEG)
    angle = float(np.clip(friction_limit, low, high))
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    radius, height = slant * np.sin(angle), slant * np.cos(angle)
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


def check_rotation(rotation: ArrayLike) -> np.ndarray:
    """``rotation`` as a (3, 3) float array, or a ValueError saying what is wrong with it."""
    return check_rotations(rotation, single=True)


def check_forces(
    forces: ArrayLike, n_contacts: int, leading: tuple[int, ...] = (), name: str = "contact_forces"
) -> np.ndarray:
    """``forces`` as a (*leading, n, 3) float array of finite real numbers (no string or
    boolean converted), or a ValueError naming ``name`` and saying what is wrong."""
    shape = (*leading, n_contacts, 3)
    must = f"finite real numbers of shape {shape}, one world-frame force per finger"
    forces = real_array(name, forces, must)
    if forces.shape != shape:
        raise ValueError(
            f"{name} must have shape {shape}, one world-frame force per finger, got {forces.shape}"
        )
    return forces


def tip_positions(scene: Scene, in_contact: np.ndarray) -> np.ndarray:
    """Object-frame fingertip centres in the model's units, (n, 3): just inside the face at the
    contact point for a finger in contact, :data:`PARK_DISTANCE` radii off it otherwise."""
    return tip_centres(model_contacts(scene), scene.normals, tip_radius(scene), in_contact)


def tip_centres(
    points: np.ndarray, normals: np.ndarray, radius: float, in_contact: ArrayLike
) -> np.ndarray:
    """Fingertip centres (..., n, 3) for contact ``points`` (..., n, 3) with inward unit
    ``normals`` (model units, object frame) and tips of ``radius``: a tip ``in_contact``
    (..., n) just inside the face (:data:`TIP_PENETRATION`), the others
    :data:`PARK_DISTANCE` radii off it. A tip whose contact point changes from pose to pose
    (a finger placed again elsewhere) takes its point at each step
    (:attr:`~grasp_env.physics.motion.Motion.points`)."""
    standoff = np.where(in_contact, radius * (1 - TIP_PENETRATION), radius * PARK_DISTANCE)
    return points - standoff[..., None] * normals


def world_qpos(
    scene: Scene, rotation: np.ndarray, in_contact: np.ndarray | None = None
) -> np.ndarray:
    """qpos of the model with the object at ``rotation`` (world frame, for drawing): its centre
    of gravity at the origin, each fingertip at its contact (or parked off it)."""
    if in_contact is None:
        in_contact = np.ones(scene.n_contacts, dtype=bool)
    qpos = np.zeros(7 + 3 * scene.n_contacts)
    qpos[:3] = -rotation @ model_cg(scene)
    qpos[3:7] = matrix_quaternion(rotation)
    qpos[7:] = ((tip_positions(scene, in_contact) - model_cg(scene)) @ rotation.T).ravel()
    return qpos


def build_mjcf(scene: Scene, timestep: float = 2e-3, visual: bool = False) -> str:
    """The MJCF text of ``scene``'s model (see the module docstring).

    The object body's frame is the box centre; its centre of gravity is the scene's
    ``cg_offset``. Joint positions (the object's pose, the fingertips' centres) are set per
    run, so one model serves every orientation. With ``visual`` the model also carries what
    :class:`~grasp_env.physics.GraspView` draws: a sky, lights and the friction cones (visual
    only: ``contype = conaffinity = 0``, group 2), which open outwards from each contact, so
    the finger's push, drawn ending at the contact, lies inside its cone exactly when it holds,
    and a cylinder's seam (:func:`seam_geom`). A box thinner than :data:`MIN_ASPECT` is refused.
    """
    check_aspect(scene)
    size = model_size(scene)
    mass = 1.0 / G
    # Uniform-box inertia about the centre of gravity, scaled (see INERTIA_SCALE).
    inertia = (
        inertia_scale(scene)
        * mass
        / 12
        * np.array(
            [size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2]
        )
    )
    radius = tip_radius(scene)
    tip_mass = TIP_MASS * mass
    tip_inertia = 0.4 * tip_mass * radius**2
    contacts = model_contacts(scene)
    condim, friction = contact_friction(scene)
    geom, mesh = object_geom(scene)
    target = object_geom_name(scene)
    fingers, pairs, motors, cones = [], [], [], []
    for i, (contact, normal) in enumerate(zip(contacts, scene.normals, strict=True)):
        fingers.append(
            f'<body name="finger{i}">'
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
        touched = f"face{i}" if touches_faces(scene) else target
        pairs.append(
            f'<pair name="contact{i}" geom1="tip{i}" geom2="{touched}" condim="{condim}"'
            f' friction="{friction}"'
            f' solref="{SOLREF}" solimp="{SOLIMP}"/>'
        )
        motors.extend(f'<motor name="finger{i}_{a}" joint="finger{i}_{a}"/>' for a in "xyz")
        cones.append(
            f'<geom name="cone{i}" type="mesh" mesh="cone" pos="{_vec(contact)}"'
            f' quat="{_vec(_z_to(-normal))}" contype="0" conaffinity="0" group="2"'
            ' rgba="0.2 0.8 0.2 0.35"/>'
        )
    visuals = assets = light = ""
    if visual:
        slant = CONE_SLANT * float(np.min(size))
        assets = (
            '<asset><texture name="sky" type="skybox" builtin="gradient" rgb1="0.85 0.9 0.95"'
            ' rgb2="0.35 0.45 0.55" width="64" height="256"/>'
            f'<mesh name="cone" vertex="{_vec(cone_vertices(scene.friction_limit, slant))}"/>'
            f"{mesh}</asset>"
        )
        visuals = "".join(cones) + seam_geom(scene)
        light = '<light pos="1 -1 3" dir="-1 1 -3" diffuse="0.5 0.5 0.5"/>'
    elif mesh:
        assets = f"<asset>{mesh}</asset>"

    return f"""<mujoco model="grasp">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep:.17g}" gravity="0 0 0" cone="elliptic" impratio="100"
          noslip_iterations="20" jacobian="dense"/>
  <visual>
    <global offwidth="1280" offheight="1280"/>
    <map znear="0.01" zfar="50"/>
    <headlight ambient="0.4 0.4 0.4" diffuse="0.6 0.6 0.6"/>
  </visual>
  <statistic center="0 0 0" extent="1"/>
  {assets}
  <worldbody>
    {light}
    <body name="object">
      <freejoint name="object"/>
      <inertial pos="{_vec(model_cg(scene))}" mass="{mass:.17g}" diaginertia="{_vec(inertia)}"/>
      {geom}
      {face_geoms(scene)}
      {visuals}
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
