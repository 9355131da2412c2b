"""``grasp-env reproduce --object``: the paper's sweep on any object and its contacts."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_FACES,
    Scene,
    Status,
    Trajectory,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.objects import Box, ConvexMesh, Cylinder, Sphere, parse_object
from grasp_env_agents.cli import main
from grasp_env_agents.commands.reproduce import newtons
from grasp_env_agents.commands.reproduce_object import (
    CONTACTS_HELP,
    finger_contacts,
    object_scene,
    parse_contacts,
    read_mesh,
)

#: A short trajectory: three poses.
SHORT = ["--alpha-start", "-5", "--alpha-end", "5", "--alpha-step", "5"]
CAN = Cylinder(radius=0.033, height=0.115)
#: The can's five fingers as --fingers 5 places them: azimuths 72 i deg, heights +-0.5.
CAN_FIVE = [CAN.side_point(np.deg2rad(72 * i), 0.5 if i % 2 == 0 else -0.5) for i in range(5)]
ATOL_RAD = 1e-9


def table_rows(printed: str) -> list[list[str]]:
    """The cells of every rich table's body rows."""
    return [
        [cell.strip() for cell in line.split("│")[1:-1]]
        for line in printed.splitlines()
        if line.startswith("│")
    ]


def read_sweep(path):
    with (path / "sweep.csv").open() as file:
        return list(csv.DictReader(file))


def prism(sides: int = 12, radius: float = 0.04, height: float = 0.1) -> np.ndarray:
    """The vertices of a regular prism: ``sides`` + 2 faces."""
    angles = 2 * np.pi * np.arange(sides) / sides
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    return np.concatenate(
        [np.column_stack([ring, np.full(sides, z)]) for z in (-height / 2, height / 2)]
    )


@pytest.fixture
def mesh_file(tmp_path):
    path = tmp_path / "hull.txt"
    lines = [" ".join(repr(float(c)) for c in v) for v in prism()]
    path.write_text("# a 12-sided prism, metres\n" + "\n".join(lines[:12]) + "\n\n")
    with path.open("a") as file:  # commas separate as well as spaces
        file.write("\n".join(",".join(line.split()) for line in lines[12:]) + "\n")
    return path


# ------------------------------------------------------------------------- end to end


@pytest.mark.parametrize("f_max", [None, 15.0])
def test_the_can_in_five_fingers(tmp_path, capsys, f_max):
    """The table is written and the printed optimum is solve_minimax's on the same scene,
    to 1e-9 rad, with its status, gap and each contact's angle, force and margin."""
    out = tmp_path / "can"
    argv = ["reproduce", "--object", "can", "--fingers", "5", *SHORT, "--out", str(out)]
    argv += [] if f_max is None else ["--f-max", str(f_max)]
    assert main(argv) == 0
    printed = capsys.readouterr().out

    scene = Scene(shape=CAN, contacts=CAN_FIVE)
    trajectory = Trajectory(alpha_start_deg=-5, alpha_end_deg=5, alpha_step_deg=5)
    grasp = scene_grasp(scene, trajectory.rotations())
    optimum = solve_minimax(grasp, 2 * scene.weight, f_max)
    limit = np.rad2deg(scene.friction_limit)

    assert "--fingers 5: --contacts='side:0,0.5;side:72,-0.5;side:144,0.5;side:216,-0.5;" in printed
    rows = table_rows(printed)
    poses, contacts = rows[:3], rows[3:]
    assert len(contacts) == 5
    for t, cells in enumerate(poses):
        assert float(cells[0]) == trajectory.alphas_deg[t]
        assert abs(np.deg2rad(float(cells[1])) - optimum.max_angle[t]) <= ATOL_RAD
        assert int(cells[2]) == np.argmax(optimum.angles[t]) + 1
        assert cells[3] == Status(int(optimum.status[t])).name.lower()
        assert float(cells[4]) == pytest.approx(np.rad2deg(optimum.gap[t]), rel=0.06, abs=1e-14)
        assert cells[5] == ("yes" if optimum.max_angle[t] <= scene.friction_limit else "NO")
    worst = int(np.argmax(optimum.max_angle))
    norms = np.linalg.norm(grasp.forces(optimum.k)[worst], axis=-1)
    for i, cells in enumerate(contacts):
        assert cells[:2] == [str(i + 1), f"side:{72 * i},{0.5 if i % 2 == 0 else -0.5:g}"]
        np.testing.assert_allclose(
            [float(c) for c in cells[2].split(",")], CAN_FIVE[i], rtol=5e-4, atol=1e-15
        )
        theta = np.rad2deg(optimum.angles[:, i])
        assert abs(np.deg2rad(float(cells[3])) - optimum.angles[worst, i]) <= ATOL_RAD
        assert cells[4] == newtons(norms[i])
        assert abs(float(cells[5]) - (limit - theta[worst])) <= np.rad2deg(ATOL_RAD)
        assert abs(float(cells[6]) - (limit - theta.max())) <= np.rad2deg(ATOL_RAD)
    if f_max is not None:
        assert np.all(norms <= f_max * (1 + 1e-9))

    saved = read_sweep(out)
    assert [float(r["alpha_deg"]) for r in saved] == [-5.0, 0.0, 5.0]
    pairs = [f"k{i}{j}" for i in range(1, 6) for j in range(i + 1, 6)]
    assert list(saved[0])[1:11] == pairs
    for t, row in enumerate(saved):
        np.testing.assert_allclose([float(row[p]) for p in pairs], optimum.k[t], rtol=1e-9)
        assert abs(np.deg2rad(float(row["theta_max_deg"])) - optimum.max_angle[t]) <= ATOL_RAD
        assert row["status"] == Status(int(optimum.status[t])).name.lower()
    assert (out / "trend.png").stat().st_size > 20_000
    assert not (out / "theta1_grid.png").exists()  # the paper's Fig. 2 is the cube's
    lines = printed.splitlines()
    assert lines[-2].startswith("statuses: ")
    assert lines[-1] == f"wrote {out / 'sweep.csv'}, {out / 'trend.png'}"


def test_the_fingers_print_the_contacts_they_place(tmp_path, capsys):
    """--fingers N says its --contacts, and that spec gives the same table."""
    common = ["reproduce", "--object", "sphere:r=0.05", "--no-plots", *SHORT]
    assert main([*common, "--fingers", "4", "--out", str(tmp_path / "a")]) == 0
    first = capsys.readouterr().out
    (spec,) = re.findall(r"^--fingers 4: --contacts='(.*)'$", first, re.MULTILINE)
    assert spec == "0,-20;90,-45;180,-20;270,-45"
    assert main([*common, f"--contacts={spec}", "--out", str(tmp_path / "b")]) == 0
    second = capsys.readouterr().out
    assert table_rows(first) == table_rows(second)
    csvs = [(tmp_path / name / "sweep.csv").read_text() for name in "ab"]
    assert csvs[0] == csvs[1]


def test_a_box_spec_is_the_paper_scene(tmp_path, capsys):
    """--object cube with the paper's faces is the paper's scene, and the run writes the
    paper run's table; offsets on the faces are Scene.on_faces's."""
    for spec in ("cube", "box", "box:size=1", "box:x=1,y=1,z=1"):
        scene, items = object_scene(
            parse_object(spec), "-x;-y;-z", weight=5.0, mu=0.5, cg_offset=(0.0, 0.0, 0.0)
        )
        assert scene == Scene() and items == PAPER_FACES
    offsets = [[0.3, 0.1], [-0.2, 0.3], [0.1, -0.3]]
    scene, _ = object_scene(
        Box(), "-x:0.3,0.1; -y:-0.2,0.3 ;-z:0.1,-0.3", weight=2.0, mu=0.7, cg_offset=(0.05, 0, 0.1)
    )
    paper = Scene.on_faces(offsets=offsets, weight=2.0, mu=0.7, cg_offset=(0.05, 0, 0.1))
    assert scene == paper

    options = [*SHORT, "--no-plots", "--cg-offset", "0.05,0,0.1", "--weight", "2"]
    assert main(["reproduce", *options, "--offsets", "0.3,0.1,-0.2,0.3,0.1,-0.3",
                 "--out", str(tmp_path / "paper")]) == 0  # fmt: skip
    contacts = "--contacts=-x:0.3,0.1;-y:-0.2,0.3;-z:0.1,-0.3"
    assert main(["reproduce", *options, "--object", "cube", contacts,
                 "--out", str(tmp_path / "cube")]) == 0  # fmt: skip
    tables = [(tmp_path / name / "sweep.csv").read_text() for name in ("paper", "cube")]
    assert tables[0] == tables[1]
    printed = capsys.readouterr().out
    assert "Minimax grip of the box:size=1.0 along the trajectory (3 contacts" in printed


# ------------------------------------------------------------------- contact syntax


def points(shape, text):
    return parse_contacts(shape, text)[0]


def test_box_contacts():
    box = Box(size=(0.1, 0.2, 0.3))
    got = points(box, "-x;+y:0.5,-0.5;-z:-0.2,0.4;@0.05,0.01,-0.02")
    expected = [[-0.05, 0, 0], [0.025, 0.1, -0.075], [-0.01, 0.04, -0.15], [0.05, 0.01, -0.02]]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(got[1], box.face_point("+y", (0.5, -0.5)))


def test_cylinder_contacts():
    r, h = CAN.radius, CAN.height
    got = points(CAN, "side:0;side:90,0.5;side:-135,-0.2;top;bottom:0.2,-0.1;@0,0.033,0")
    c = np.sqrt(0.5)
    expected = [
        [r, 0, 0],
        [0, r, 0.25 * h],
        [-c * r, -c * r, -0.1 * h],
        [0, 0, h / 2],
        [0.2 * r, -0.1 * r, -h / 2],
        [0, r, 0],
    ]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(got[1], CAN.side_point(np.pi / 2, 0.5))
    np.testing.assert_array_equal(got[4], CAN.cap_point("-z", (0.2, -0.1)))


def test_sphere_contacts():
    r = 0.05
    sphere = Sphere(radius=r)
    got = points(sphere, "0,0;90,0;0,90;120,30;240,-30;@0,0,-0.05")
    s3 = np.sqrt(3) / 2
    expected = [
        [r, 0, 0],
        [0, r, 0],
        [0, 0, r],
        [-s3 / 2 * r, s3 * s3 * r, r / 2],
        [-s3 / 2 * r, -s3 * s3 * r, -r / 2],
        [0, 0, -r],
    ]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)


def test_mesh_contacts(mesh_file):
    mesh = read_mesh(mesh_file)
    assert mesh == ConvexMesh(vertices=prism())
    assert [len(face) for face in mesh.faces].count(12) == 2  # and 12 sides of 4 vertices
    assert len(mesh.faces) == 14  # (face 11 is a cap)
    assert len(mesh.faces[11]) == 12
    got = points(mesh, "3;7;11:1,2,3,4,5,6,7,8,9,10,11,12;@0.01,0.02,0.05")
    np.testing.assert_array_equal(got[0], mesh.face_point(3))
    np.testing.assert_array_equal(got[1], mesh.face_point(7))
    np.testing.assert_array_equal(got[2], mesh.face_point(11, np.arange(1, 13)))
    np.testing.assert_array_equal(got[3], [0.01, 0.02, 0.05])


def test_every_help_example_parses(mesh_file):
    examples = re.findall(r"e\.g\. --object (\S+) --contacts='([^']*)'", CONTACTS_HELP)
    assert len(examples) == 5
    for spec, text in examples:
        shape = read_mesh(mesh_file) if spec == "mesh:hull.txt" else parse_object(spec)
        assert len(points(shape, text)) == 3


@pytest.mark.parametrize(
    "shape", [Box(size=(0.1, 0.2, 0.3)), CAN, Sphere(radius=0.05), ConvexMesh(vertices=prism())]
)
@pytest.mark.parametrize("count", range(3, 9))
def test_the_fingers_make_a_valid_grasp(shape, count):
    """--fingers N: N contacts on the surface, none coinciding, not coplanar (Scene checks)."""
    scene, items = object_scene(
        shape, finger_contacts(shape, count), weight=5.0, mu=0.5, cg_offset=(0, 0, 0)
    )
    assert scene.n_contacts == len(items) == count


def test_help_gives_an_example_per_shape(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["reproduce", "--help"])
    assert stop.value.code == 0
    printed = capsys.readouterr().out
    for example in (
        "--contacts='-x;-y:0.2,0.1;+z'",
        "--contacts='side:0;side:72,0.3;top:0.2,0.1'",
        "--contacts='0,0;120,30;240,-30'",
        "--contacts='3;7;12'",
        "@X,Y,Z",
        "--fingers N",
    ):
        assert example in printed


# ---------------------------------------------------------------------- bad inputs

FORM = "a cylinder's contacts are side:ANGLE_DEG[,HEIGHT]"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--object", "cone", "--fingers", "3"], "argument --object: unknown object 'cone'"),
        (["--object", "sphere:r=-1", "--fingers", "3"], "argument --object: object 'sphere:r=-1'"),
        (["--object", "mesh:nowhere.txt", "--fingers", "3"], "mesh nowhere.txt: No such file"),
        (["--object", "mesh:BAD", "--fingers", "3"], "line 2 must be a vertex 'x y z'"),
        (["--object", "can", "--contacts=side:0;side:abc;top"],
         "--contacts: contact 2 'side:abc': expected ANGLE_DEG[,HEIGHT]"),
        (["--object", "can", "--contacts=side:0;side:72;top;nowhere"],
         f"--contacts: contact 4 'nowhere': unknown place 'nowhere', expected side, top or"
         f" bottom; {FORM}"),
        (["--object", "can", "--contacts=side:0;top"],
         f"--contacts: 2 contacts given, a grasp takes 3 to 8 separated by ';'; {FORM}"),
        (["--object", "can", "--contacts=" + ";".join(f"side:{a}" for a in range(9))],
         "--contacts: 9 contacts given, a grasp takes 3 to 8"),
        (["--object", "can", "--contacts=side:0;;top"], "--contacts: contact 2 '': empty"),
        (["--object", "can", "--contacts=side:0;side:90,1;top"],
         "--contacts: contact 2 'side:90,1': side height (a fraction of the half-height)"
         " must be a finite number in (-1, 1)"),
        (["--object", "cube", "--contacts=@0.6,0,0;-y;-z"],
         "--contacts: contact 1 '@0.6,0,0' at [0.6, 0.0, 0.0] lies outside the box"),
        (["--object", "cube", "--contacts=-y;-z;@0.2,0,0"],
         "--contacts: contact 3 '@0.2,0,0' at [0.2, 0.0, 0.0] is not on a face of the box"),
        (["--object", "cube", "--contacts=-y;@0.5,0.5,0;-z"], "is on an edge"),
        (["--object", "cube", "--contacts=-q;-y;-z"], "contact 1 '-q': unknown face '-q'"),
        (["--object", "cube", "--contacts=-x;@nan,0,0;-z"],
         "contact 2 '@nan,0,0': expected X,Y,Z in metres (3 finite comma-separated numbers)"),
        (["--object", "sphere:r=1", "--contacts=0,0;90,0;inf,0"],
         "contact 3 'inf,0': expected AZIMUTH_DEG,ELEVATION_DEG (2 finite comma-separated"),
        (["--object", "sphere:r=1", "--contacts=0,100;0,0;90,0"],
         "contact 1 '0,100': the elevation must be in [-90, 90] deg"),
        (["--object", "can", "--contacts=side:0;side:0;top"],
         "--contacts: contacts 1 'side:0' and 2 'side:0' coincide"),
        (["--object", "can", "--contacts=side:0;side:90;side:180;side:270"],
         "--contacts: the 4 contacts are coplanar"),
        (["--object", "cube", "--contacts=-x:0.5,0;-x;-x:-0.5,0"],
         "--contacts: the 3 contacts are collinear"),
        (["--object", "can", "--fingers", "9"], "argument --fingers: must be an integer in [3, 8]"),
        (["--object", "can", "--fingers", "4", "--cg-offset", "0,0,1"],
         "--cg-offset: cg_offset [0.0, 0.0, 1.0] must lie inside the cylinder"),
        (["--object", "can", "--fingers", "4", "--offsets", "0,0,0,0,0,0"],
         "--offsets moves the paper cube's face-centre contacts"),
        (["--object", "can"], "--object needs its contacts: give --contacts or --fingers"),
        (["--contacts=-x;-y;-z"], "--contacts places contacts on --object's surface"),
        (["--object", "can", "--fingers", "3", "--contacts=side:0;side:90;top"],
         "argument --contacts: not allowed with argument --fingers"),
        (["--f-max", "0"], "argument --f-max: must be a finite number of newtons > 0"),
    ],
)  # fmt: skip
def test_bad_inputs_give_one_line_errors(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "BAD").write_text("0 0 0\n1 2\n")
    out = tmp_path / "out"
    try:
        code = main(["reproduce", *args, *SHORT, "--no-plots", "--out", str(out)])
    except SystemExit as stop:  # refused by argparse, before the command runs
        code = stop.code
    assert code == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    (line,) = [line for line in captured.err.splitlines() if "error" in line]
    assert line.startswith("grasp-env reproduce: error: ")
    assert message in line
    assert captured.out == "" and not out.exists()
