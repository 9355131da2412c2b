"""The package's shape: the layers import one way, the environments register in any import
order, and pyproject.toml ships every package of the source tree."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("gymnasium", "mujoco", "torch", "stable_baselines3", "grasp_env_agents")


def loaded_after(statement: str) -> set[str]:
    """The heavy top-level modules that ``statement`` loads, in a fresh interpreter."""
    probe = f"import sys; {statement}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True
    )
    return set(done.stdout.split())


@pytest.mark.parametrize(
    ("module", "allowed"),
    [
        ("grasp_env", set()),
        pytest.param("grasp_env.mechanics", set(), marks=pytest.mark.fast),
        ("grasp_env.physics", {"mujoco"}),
        ("grasp_env.envs", {"gymnasium"}),
    ],
)
def test_layers_import_one_way(module, allowed):
    """mechanics loads no gymnasium, mujoco or torch; physics only MuJoCo; envs only gymnasium."""
    assert loaded_after(f"import {module}") <= allowed


def imported_modules(path: Path) -> set[str]:
    """Absolute names of the modules a source file imports (relative imports resolved)."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            names.add(".".join(p for p in (base, node.module or "") if p))
    return names


@pytest.mark.parametrize(
    ("layer", "forbidden"),
    [
        ("grasp_env/mechanics", ("grasp_env.envs", "grasp_env.physics", "gymnasium", "mujoco")),
        ("grasp_env/physics", ("grasp_env.envs", "gymnasium", "torch", "stable_baselines3")),
        ("grasp_env", ("grasp_env_agents", "torch")),
    ],
)
@pytest.mark.fast
def test_no_import_points_back(layer, forbidden):
    """Statically, anywhere in the layer (lazy imports inside functions included)."""
    for path in sorted((ROOT / layer).rglob("*.py")):
        bad = [
            name
            for name in imported_modules(path)
            if any(name == f or name.startswith(f + ".") for f in forbidden)
        ]
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize(
    "statement",
    [
        "import grasp_env; import gymnasium as gym",
        "import gymnasium as gym; import grasp_env",
        "import grasp_env.mechanics; import gymnasium as gym; import grasp_env",
    ],
)
def test_environments_register_in_any_import_order(statement):
    probe = f"{statement}; print(gym.make('grasp_env/CubeGrasp-v0').unwrapped.spec.id)"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "grasp_env/CubeGrasp-v0"


#: The folders whose packages ship (pyproject.toml's packages and package-dir): only these are
#: walked, so a virtual environment, a build tree or docs inside the clone are not packages.
SOURCE_FOLDERS = ("grasp_env", "agents", "benchmarks", "configs")


def source_packages(root: Path, package_dir: dict[str, str]) -> set[str]:
    """The packages (folders holding an ``__init__.py``) under ``root``'s SOURCE_FOLDERS, under
    their installed names (``package_dir``: installed name -> folder, as in pyproject.toml)."""
    installed = {folder: name for name, folder in package_dir.items()}
    found = set()
    for folder in SOURCE_FOLDERS:
        for init in (root / folder).glob("**/__init__.py"):
            top, *rest = init.parent.relative_to(root).parts
            found.add(".".join([installed.get(top, top), *rest]))
    return found


@pytest.mark.fast
def test_pyproject_ships_every_package():
    """find cannot see the mapped packages, so pyproject.toml lists them: the list must be the
    source tree's packages, under their installed names."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert set(setuptools["package-dir"].values()) <= set(SOURCE_FOLDERS)
    found = source_packages(ROOT, setuptools["package-dir"])
    assert sorted(found) == sorted(setuptools["packages"])


@pytest.mark.fast
def test_source_packages_skip_a_venv_and_build_trees_in_the_clone(tmp_path):
    """``python -m venv .venv`` inside the clone put 2,406 packages of site-packages in the list."""
    for folder in (
        "grasp_env/envs",
        "agents",
        "configs",
        ".venv/lib/python3.11/site-packages/foo",
        "build/lib/grasp_env",
        "tests",
        "docs/examples",
    ):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "__init__.py").write_text("")
    (tmp_path / "grasp_env/envs/kernels.py").write_text("")
    package_dir = {"grasp_env_agents": "agents", "grasp_env_agents.configs": "configs"}
    assert source_packages(tmp_path, package_dir) == {
        "grasp_env.envs",
        "grasp_env_agents",
        "grasp_env_agents.configs",
    }


def pyproject_names(requirements: list[str]) -> set[str]:
    """The distribution names of pyproject requirement strings, normalised (lower case, -)."""
    return {
        re.split(r"[\[<>=!~;\s]", r, maxsplit=1)[0].lower().replace("_", "-") for r in requirements
    }


#: distribution -> import name, where they differ (the agents extra's)
IMPORT_NAMES = {
    "stable-baselines3": "stable_baselines3",
    "sb3-contrib": "sb3_contrib",
    "pyyaml": "yaml",
}


@pytest.mark.fast
def test_the_library_installs_without_the_learning_stack():
    """``pip install grasp-env`` is the solver, the environments and the physics check; the
    ``agents`` extra (which ``test`` includes) brings torch, SB3 and what the CLI needs, and the
    CLI names exactly those modules when one is missing."""
    from grasp_env_agents import cli

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    agents = pyproject_names(extras["agents"])
    assert {"torch", "stable-baselines3", "tensorboard"} <= agents
    assert not agents & pyproject_names(project["dependencies"])
    assert {IMPORT_NAMES.get(name, name) for name in agents} == set(cli.AGENTS_EXTRA)
    assert any(r.startswith("grasp-env[") and "agents" in r for r in extras["test"])


#: Third-party imports of the library outside its dependencies, by file: each is optional there.
OPTIONAL_IMPORTS = {
    "grasp_env/_build.py": {"setuptools"},  # the wheel build's step (build-system.requires)
    "grasp_env/envs/sb3.py": {"stable_baselines3"},  # the SB3 adapter: the agents extra
    "grasp_env/physics/render.py": {"glfw", "PIL"},  # glfw: mujoco's; PIL: text overlays only
}


@pytest.mark.fast
def test_the_library_imports_only_its_dependencies():
    """Statically, every third-party module a file of grasp_env/ imports (lazy ones included) is
    one of its dependencies (numpy, numba, scipy, gymnasium, mujoco) or listed as optional."""
    dependencies = pyproject_names(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    )
    for path in sorted((ROOT / "grasp_env").rglob("*.py")):
        name = path.relative_to(ROOT).as_posix()
        tops = {module.split(".")[0] for module in imported_modules(path)}
        third_party = tops - set(sys.stdlib_module_names) - {"grasp_env", "__future__"}
        assert third_party <= dependencies | OPTIONAL_IMPORTS.get(name, set()), name


def test_the_library_works_without_torch_and_sb3():
    """In an interpreter where torch, SB3 and the agents extra's other modules cannot be
    imported: grasp_env, its mechanics, environments and physics import, a single and a vector
    environment step, and the SB3 adapter says which extra it needs."""
    from grasp_env_agents import cli

    probe = f"""
import sys
for name in {cli.AGENTS_EXTRA!r}:
    sys.modules[name] = None  # import name -> ModuleNotFoundError
import gymnasium as gym
import numpy as np
import grasp_env, grasp_env.envs, grasp_env.mechanics, grasp_env.physics
env = gym.make("grasp_env/CubeGrasp-v0")
env.reset(seed=0)
_, reward, *_ = env.step(env.action_space.sample())
envs = gym.make_vec("grasp_env/CubeGraspRandom-v0", num_envs=2,
                    vectorization_mode="vector_entry_point")
envs.reset(seed=0)
_, rewards, *_ = envs.step(envs.action_space.sample())
assert np.isfinite(reward) and np.all(np.isfinite(rewards)), (reward, rewards)
try:
    import grasp_env.envs.sb3
except ImportError as error:
    print(error)
print(sorted(m for m in {cli.AGENTS_EXTRA!r} if sys.modules.get(m) is not None))
"""
    # (minutes where the solver is not compiled yet: the environments solve at reset)
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-3000:]
    adapter, loaded = done.stdout.strip().splitlines()[-2:]
    assert loaded == "[]"
    assert "stable_baselines3 is not installed" in adapter
    assert 'pip install "torch==2.13.0" "grasp-env[agents]"' in adapter


@pytest.mark.fast
def test_the_cli_without_torch_names_the_agents_extra(monkeypatch, capsys):
    """``pip install grasp-env`` and then ``grasp-env``: one line saying what to install."""
    from grasp_env_agents import cli

    monkeypatch.setitem(sys.modules, "torch", None)
    assert cli.main(["reproduce"]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert lines == [
        "grasp-env needs the agents extra (torch not installed): "
        'pip install "torch==2.13.0" "grasp-env[agents]"'
    ]


@pytest.mark.fast
def test_every_command_has_help():
    """``grasp-env --help`` and each command's ``--help`` print and exit 0 (argparse formats
    help strings with %, so a stray % crashes them)."""
    from grasp_env_agents import cli

    for argv in [[], *([name] for name in cli.SUMMARIES)]:
        with pytest.raises(SystemExit) as done:
            cli.main([*argv, "--help"])
        assert done.value.code == 0, argv


def test_ctrl_c_while_a_command_loads_exits_130(monkeypatch, capsys):
    """Ctrl-C during the seconds a command spends importing torch and SB3: a line, no
    traceback."""
    from grasp_env_agents import cli

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    assert cli.main(["train"]) == 130
    assert capsys.readouterr().err.strip().endswith("interrupted")


def agents_modules() -> dict[str, Path]:
    """Every module of grasp_env_agents (the repository's agents/ folder), by import name."""
    modules = {}
    for path in sorted((ROOT / "agents").rglob("*.py")):
        parts = path.relative_to(ROOT / "agents").with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(("grasp_env_agents", *parts))] = path
    return modules


def agents_import_graph() -> dict[str, set[str]]:
    """Which modules of grasp_env_agents each one imports, statically: imports inside
    functions and under ``TYPE_CHECKING`` included, ``from package import module`` resolved
    to the module."""
    modules = agents_modules()
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = package.rsplit(".", node.level - 1)[0] if node.level else ""
                target = ".".join(p for p in (base, node.module or "") if p)
                for alias in node.names:
                    member = f"{target}.{alias.name}"
                    found.add(member if member in modules else target)
        graph[name] = {other for other in found if other in modules and other != name}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The cycles a depth-first search meets in ``graph`` (empty when it is acyclic)."""
    state: dict[str, int] = {}  # 1 while on the path, 2 when done
    path: list[str] = []
    cycles = []

    def visit(node: str) -> None:
        state[node] = 1
        path.append(node)
        for after in sorted(graph[node]):
            if state.get(after) == 1:
                cycles.append([*path[path.index(after) :], after])
            elif after not in state:
                visit(after)
        path.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    return cycles


@pytest.mark.fast
def test_import_cycles_are_found():
    """The search itself: a module importing one that imports it back is a cycle."""
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == [["a", "b", "c", "a"]]


@pytest.mark.fast
def test_no_module_of_the_agents_imports_itself_back():
    """No module of grasp_env_agents imports one that imports it back, not even lazily inside a
    function (a cycle hidden that way still couples the two)."""
    graph = agents_import_graph()
    assert len(graph) > 30
    assert graph["grasp_env_agents.studies.results"] >= {"grasp_env_agents.studies.evaluation"}
    assert import_cycles(graph) == []


def test_every_module_of_the_agents_imports_in_a_fresh_interpreter():
    """Each module alone, first thing in a new process: an import that only works after another
    module has loaded would fail here."""
    names = sorted(agents_modules())
    probe = (
        "import importlib, sys\n"
        "for name in sys.argv[1:]:\n"
        "    importlib.import_module(name)\n"
        "    for loaded in [m for m in sys.modules if m.startswith('grasp_env_agents')]:\n"
        "        del sys.modules[loaded]\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe, *names], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.fast
def test_no_file_of_the_agents_is_past_600_lines():
    """A file past 600 lines holds more than one role: split it."""
    long = {
        str(path.relative_to(ROOT)): lines
        for path in agents_modules().values()
        if (lines := len(path.read_text().splitlines())) > 600
    }
    assert long == {}
