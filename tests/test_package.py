"""The package's shape: the layers import one way, the environments register in any import
order, and pyproject.toml ships every package of the source tree."""

from __future__ import annotations

import ast
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
        ("grasp_env.mechanics", set()),
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


def test_pyproject_ships_every_package():
    """find cannot see the mapped packages, so pyproject.toml lists them: the list must be the
    source tree's packages, under their installed names."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {folder: name for name, folder in setuptools["package-dir"].items()}
    found = set()
    for init in ROOT.glob("**/__init__.py"):
        parts = init.parent.relative_to(ROOT).parts
        if parts[0] in ("tests", "build", ".git"):
            continue
        top = parts[0] if parts[0] in folders else None  # a mapped folder: its installed name
        found.add(".".join([folders[top], *parts[1:]] if top else parts))
    assert sorted(found) == sorted(setuptools["packages"])


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
