"""The certified minimax optimiser's compiled kernels: their cache keys, the one compiled
signature, the stack arrays and the LU solve.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import subprocess
import sys

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_AXIS,
    Grasp,
    Scene,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)

CALLEE = (
    "from grasp_env.mechanics.minimax.jit import kernel\n\n\n@kernel\ndef value():\n    return {}\n"
)


CALLER = (
    "from grasp_env.mechanics.minimax.jit import entry\n\nfrom .callee import value\n\n\n"
    "@entry\ndef call():\n    return value()\n"
)


KEYED = (
    "import os\n\nfrom grasp_env.mechanics.minimax import jit\n\n"
    "jit.register_package(os.path.dirname(__file__))\n"
)


def test_kernel_cache_follows_an_edited_callee(tmp_path) -> None:
    """numba checks only the cached function's own file, but its machine code holds its
    callees' from other modules; the kernels' cache is keyed on every module of their package,
    so an edit to a callee in another module recompiles the caller (run in subprocesses, on a
    small package made with the kernels' decorators, as the solver's would take a minute)."""
    package = tmp_path / "kernels_copy"
    package.mkdir()
    (package / "__init__.py").write_text(KEYED)
    (package / "caller.py").write_text(CALLER)
    script = (
        "from kernels_copy.caller import call; "
        "print(call(), sum(call.stats.cache_hits.values()), sum(call.stats.cache_misses.values()))"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}

    def run() -> list[int]:
        done = subprocess.run(
            [sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        return [int(word) for word in done.stdout.split()]

    (package / "callee.py").write_text(CALLEE.format(1))
    assert run() == [1, 0, 1]  # compiled
    assert run() == [1, 1, 0]  # loaded from the cache
    (package / "callee.py").write_text(CALLEE.format(2))
    assert run() == [2, 0, 1]  # the caller's file did not change, yet it is compiled again
    assert run() == [2, 1, 0]


def test_every_kernel_is_keyed_on_its_package() -> None:
    """Every compiled function of the solver's package uses the package-keyed cache."""
    from numba.core.registry import CPUDispatcher

    import grasp_env.mechanics.minimax as package
    from grasp_env.mechanics.minimax import jit

    count = 0
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                assert isinstance(value._cache._impl.locator, jit.LOCATORS), value
                count += 1
    assert count >= 30


@pytest.mark.fast
def test_every_way_in_reaches_the_one_compiled_signature() -> None:
    """The wheel ships numba's cache of the solver's entries as warm.py compiles them; any other
    array type (a read-only view, another dtype) would compile the whole solver again, minutes
    at a user's first command. Every way of calling solve_minimax reaches those same types."""
    from grasp_env.mechanics.minimax import driver
    from grasp_env.mechanics.minimax.warm import warm

    warm()
    scene = Scene.on_faces(offsets=[[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]])
    rotations = np.stack([pose_rotation(PAPER_AXIS, np.radians(a)) for a in (-5.0, 0.0, 5.0)])
    moving = scene_grasp(scene, rotations)
    arrays = [np.array(a) for a in (moving.positions, moving.normals, moving.equilibrating)]
    arrays.append(np.array(moving.basis, dtype=np.float32))  # another dtype
    for array in arrays:
        array.flags.writeable = False
    read_only = Grasp(*arrays, friction_limit=moving.friction_limit)
    follows = np.array([False, True, True])
    frozen = follows.copy()
    frozen.flags.writeable = False
    weight = 2.0 * scene.weight
    for kwargs in (
        {},
        {"follows": follows},  # as the environments pass it: the batch's own shape
        {"follows": frozen},
        {"follows": True},
        {"f_max": np.full(3, 4.0 * scene.weight)},
    ):
        solve_minimax(moving, weight, **kwargs)
    solve_minimax(read_only, 2, follows=follows)
    solve_minimax(scene_grasp(scene, rotations[1]), weight)
    assert len(driver.solve_batch.signatures) == 1, driver.solve_batch.signatures
    assert len(driver.solve_grasp.signatures) == 1, driver.solve_grasp.signatures


def test_stack_arrays_behave_as_numpys() -> None:
    """The kernels' stack arrays (linalg.stack_*): numpy's shapes, dtypes and values, each call
    site its own memory, every item of a full room writable, and an array beyond its room
    refused (there is no heap to fall back on)."""
    from numba import njit

    from grasp_env.mechanics.minimax.linalg import (
        LARGE_ITEMS,
        VECTOR_ITEMS,
        stack_copy,
        stack_empty,
        stack_large,
        stack_zeros,
    )

    @njit
    def made(n: int, items: int, large_rows: int):  # type: ignore[no-untyped-def]
        zeros = stack_zeros((n, 3))
        flags = stack_zeros(n, dtype=np.bool_)
        counts = stack_empty(n, dtype=np.int64)
        counts.fill(7)
        other = stack_zeros((n, 3))  # another call site: not the first's memory
        other[0, 0] = 1.0
        copied = stack_copy(other)
        other[0, 0] = 2.0
        full = stack_empty(items)
        for q in range(items):
            full[q] = q
        large = stack_large((large_rows, 24))
        large[large_rows - 1, 23] = 1.0
        # (copies on the heap: a stack array must not outlive its kernel)
        return zeros.copy(), flags.copy(), counts.copy(), copied.copy(), full.sum(), large.sum()

    zeros, flags, counts, copied, total, ones = made(4, VECTOR_ITEMS, LARGE_ITEMS // 24)
    assert zeros.shape == (4, 3) and zeros.dtype == np.float64 and not zeros.any()
    assert flags.dtype == np.bool_ and not flags.any()
    assert counts.dtype == np.int64 and (counts == 7).all()
    assert copied[0, 0] == 1.0 and copied.sum() == 1.0
    assert total == sum(range(VECTOR_ITEMS)) and ones == 1.0
    with pytest.raises(ValueError, match="beyond its room"):
        made(4, VECTOR_ITEMS + 1, 1)
    with pytest.raises(ValueError, match="beyond its room"):
        made(4, 1, LARGE_ITEMS // 24 + 1)


def test_lu_solve_matches_numpy_at_every_size() -> None:
    """linalg.lu_solve solves as numpy does at every size a solve uses, pivoting where the
    leading entry is zero, and refuses a singular matrix."""
    from numba import njit

    from grasp_env.mechanics.minimax.linalg import lu_solve

    @njit
    def solve(A, b):  # type: ignore[no-untyped-def]
        A, b = A.copy(), b.copy()
        return lu_solve(A, b, A.shape[0]), b

    rng = np.random.default_rng(0)
    for size in range(2, 12):
        for _ in range(5):
            A = rng.normal(size=(size, size))
            A[0, 0] = 0.0  # the first column needs a pivot
            b = rng.normal(size=size)
            ok, x = solve(A, b)
            assert ok and np.allclose(x, np.linalg.solve(A, b), rtol=1e-10, atol=1e-12), size
        A[-1] = A[0]  # two equal rows
        assert not solve(A, b)[0], size
