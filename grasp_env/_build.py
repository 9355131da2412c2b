"""Build step (pyproject.toml's ``[tool.setuptools.cmdclass]``; not imported at run time).

After copying the sources into the build tree, compile the minimax solver there
(:mod:`grasp_env.mechanics.minimax.warm`), so that the wheel ships numba's cache and the first
command after installing it does not spend minutes compiling. Editable installs use the
source tree, whose cache fills on first use.
"""

from __future__ import annotations

import os
import subprocess
import sys

from setuptools.command.build_py import build_py


class BuildPy(build_py):
    def run(self) -> None:
        super().run()
        if self.editable_mode or self.dry_run:
            return
        env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}
        # the build tree first, then what the build runs on: pip's isolated build environment
        # reaches a child process through PYTHONPATH (numpy and numba live there, not in the
        # interpreter's own site-packages when installing into a fresh venv)
        paths = [os.path.abspath(self.build_lib), os.environ.get("PYTHONPATH", "")]
        env["PYTHONPATH"] = os.pathsep.join(path for path in paths if path)
        self.announce("compiling the minimax solver into the wheel's numba cache", level=2)
        subprocess.run(
            [sys.executable, "-m", "grasp_env.mechanics.minimax.warm"],
            cwd=self.build_lib,
            env=env,
            check=True,
        )
