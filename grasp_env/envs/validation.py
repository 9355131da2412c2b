"""Checks of the environments' keywords, options, seeds and actions: one validator per rule,
each raising a ValueError that names the input and the accepted range (docs/environments.md,
"Accepted inputs"); a vector env's reset mask of the wrong type is a TypeError, as Gymnasium's.

Numbers must be real numbers (Python or numpy ints and floats): booleans, complex numbers,
strings and None are refused rather than converted, and flags must be booleans.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

# the mechanics' rules for numbers, shared (check_number: a finite real number in a range)
from ..mechanics.checks import is_integer, real_array
from ..mechanics.checks import real_number as check_number

# re-exported: the environments' pose cap is the trajectories' (each pose a solve at a reset)
from ..mechanics.trajectory import MAX_POSES as MAX_POSES
from ..mechanics.trajectory import Trajectory
from .spec import ALPHA, K_MAX_RATIO, K_MAX_RATIO_MUJOCO, MIN_EXPERT_MARGIN, MU, WEIGHT

# The accepted ranges (closed), from the keywords' records (spec.py). The mechanics are
# computed in units of w, so rewards do not depend on the weight at all; the weight range
# keeps the forces reported in newtons (and the MuJoCo model's masses) far from overflow.
DEFAULT_K_MAX_RATIO = K_MAX_RATIO.default
WEIGHT_RANGE = WEIGHT.range  # N
MU_RANGE = MU.range  # theta_lim from 0.057 deg to 89.94 deg
K_MAX_RATIO_RANGE = K_MAX_RATIO.range  # k_max / w
MUJOCO_K_MAX_RATIO_RANGE = K_MAX_RATIO_MUJOCO.range  # (spec.K_MAX_RATIO_MUJOCO: why)
ALPHA_RANGE_DEG = ALPHA.range
#: The most sub-environments a vector environment may have.
MAX_ENVS = 1 << 20


def check_bool(name: str, value: Any) -> bool:
    """A flag: True or False (numbers and strings are refused, not interpreted)."""
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_integer(name: str, value: Any, low: int, high: int) -> int:
    """An integer (not a boolean) in [low, high]."""
    if not is_integer(value):
        raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    if not low <= int(value) <= high:
        raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    return int(value)


def check_range(
    name: str, value: Any, low: float, high: float, *, open_low: bool = False
) -> tuple[float, float]:
    """A (low, high) pair of numbers with low <= high within [low, high]."""
    bracket = "(" if open_low else "["
    message = (
        f"{name} must be a (low, high) pair with low <= high within {bracket}{low:g}, {high:g}]"
    )
    if isinstance(value, str | bytes | Mapping) or not isinstance(value, Sequence | np.ndarray):
        raise ValueError(f"{message}, got {value!r}")
    if len(value) != 2:
        raise ValueError(f"{message}, got {value!r}")
    try:
        lo, hi = (check_number(name, v, low, high, open_low=open_low) for v in value)
    except ValueError:
        raise ValueError(f"{message}, got {value!r}") from None
    if hi < lo:
        raise ValueError(f"{message}, got {value!r}")
    return lo, hi


def check_fraction(name: str, value: Any, high: float = 1.0, *, closed: bool = False) -> float:
    """A number in [0, high) (or [0, high] if ``closed``)."""
    return check_number(name, value, 0.0, high, open_high=not closed)


def check_margin(value: Any) -> float:
    """``min_expert_margin_deg`` in [0, 45) degrees, returned in radians."""
    return float(np.deg2rad(MIN_EXPERT_MARGIN.check(value)))


def check_k_max_ratio(value: Any) -> float:
    """``k_max_ratio`` = k_max / w in :data:`K_MAX_RATIO_RANGE`."""
    return K_MAX_RATIO.check(value)


def check_mujoco_k_max_ratio(value: Any) -> float:
    """``k_max_ratio`` of an environment checked in MuJoCo, in :data:`MUJOCO_K_MAX_RATIO_RANGE`."""
    return K_MAX_RATIO_MUJOCO.check(value, "k_max_ratio (with physics='mujoco')")


def check_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A C-contiguous float64 array of ``shape`` from real numbers (no booleans, complex
    numbers or strings), all finite."""
    must = f"an array of shape {shape} of finite real numbers"
    array = real_array(name, value, must)
    if array.shape != shape:
        raise ValueError(f"{name} must be {must}, got shape {array.shape}")
    return np.ascontiguousarray(array)


_KERNEL_DTYPES = (np.dtype(np.float64), np.dtype(np.float32))  # the step kernel's compiled types


def action_array(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as a float array of ``shape``, or a ValueError saying what an action must be
    (real numbers: booleans, complex numbers and strings are refused; finiteness is checked
    by the step kernel)."""
    if (
        type(action) is np.ndarray
        and action.dtype in _KERNEL_DTYPES
        and action.shape == shape
        and action.flags.c_contiguous
    ):
        return action  # the common case, kept cheap
    return check_array("action", action, shape)


def check_seed(name: str, value: Any) -> int | None:
    """A seed: None or an integer >= 0 (numpy integers too; booleans are refused)."""
    if value is None:
        return None
    if not is_integer(value) or value < 0:
        raise ValueError(f"{name} must be None or an integer >= 0, got {value!r}")
    return int(value)


def check_max_episode_steps(value: Any) -> int | None:
    """A vector environment's time limit (``gym.make_vec(..., max_episode_steps=...)``): None
    (none), -1 (none either: ``gym.make``'s way to drop an id's registered limit) or an
    integer >= 1 (numpy integers too; booleans are refused)."""
    if value is None or (is_integer(value) and value == -1):
        return None
    if not is_integer(value) or value < 1:
        raise ValueError(
            f"max_episode_steps must be None, -1 (no limit) or an integer >= 1, got {value!r}"
        )
    return int(value)


#: The autoreset modes of the batched vector environments: all of Gymnasium's.
AUTORESET_MODES = tuple(AutoresetMode)


def check_autoreset_mode(value: Any) -> AutoresetMode:
    """An :class:`~gymnasium.vector.AutoresetMode` or its value (``"NextStep"``,
    ``"SameStep"``, ``"Disabled"``)."""
    try:
        return AutoresetMode(value)
    except (ValueError, TypeError):
        raise ValueError(
            f"autoreset_mode must be one of {[m.value for m in AUTORESET_MODES]} (or the"
            f" AutoresetMode members), got {value!r}"
        ) from None


_MASK_FORM = "a numpy array of dtype bool and shape ({},), True for the sub-environments to reset"


def split_reset_mask(options: Any, num_envs: int) -> tuple[np.ndarray | None, Any]:
    """Gymnasium's ``reset(options={"reset_mask": mask, ...})`` of a vector environment: the
    checked mask (a copy) and the other options (a new mapping; the caller's is left as it
    is), or ``(None, options)`` when there is no mask.

    As Gymnasium's ``SyncVectorEnv``, the mask must be a numpy array (TypeError otherwise) of
    shape ``(num_envs,)`` (ValueError) and dtype bool (TypeError), with at least one True
    (ValueError).
    """
    if not isinstance(options, Mapping) or "reset_mask" not in options:
        return None, options
    mask = options["reset_mask"]
    form = _MASK_FORM.format(num_envs)
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"options['reset_mask'] must be {form}; got a {type(mask).__name__}")
    if mask.shape != (num_envs,):
        raise ValueError(f"options['reset_mask'] must be {form}; got shape {mask.shape}")
    if mask.dtype != np.bool_:
        raise TypeError(f"options['reset_mask'] must be {form}; got dtype {mask.dtype}")
    if not mask.any():
        raise ValueError(
            f"options['reset_mask'] must be {form}, at least one of them; got all False"
        )
    rest = {key: value for key, value in options.items() if key != "reset_mask"}
    return mask.copy(), rest


def refuse_ended(mode: AutoresetMode, ended: np.ndarray) -> None:
    """A vector env's step with autoreset ``mode``: a RuntimeError, naming them, if it is
    DISABLED and sub-environments' episodes have ended (``ended``, (num_envs,) bool) without
    a reset since."""
    if mode != AutoresetMode.DISABLED or not ended.any():
        return
    which = np.flatnonzero(ended)
    listed = f"{which[:20].tolist()}" + (f" and {len(which) - 20} more" if len(which) > 20 else "")
    shown = np.array2string(ended, separator=", ", threshold=16)
    raise RuntimeError(
        f"the episodes of sub-environments {listed} have ended and autoreset_mode is"
        " DISABLED: reset them before the next step with"
        " reset(options={'reset_mask': mask}), mask a numpy bool array of shape"
        f" ({len(ended)},) True for them (here {shown})"
    )


def end_step(
    mode: AutoresetMode,
    observations: np.ndarray,
    info: dict[str, Any],
    done: np.ndarray,
    mask: np.ndarray,
    restart: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """A vector env's step under autoreset ``mode``, finished in place on its
    ``observations`` and ``info``; ``done`` (num_envs,) marks the episodes that ended.

    SAME_STEP, when some ended: as Gymnasium's SyncVectorEnv, their last observation and info
    move to ``final_obs`` and ``final_info``, and ``restart(ended)`` (their indices) starts
    their next episodes and returns its first observations. Otherwise every info key gets the
    mask ``mask``. Returns the sub-environments whose episodes the next step must reset
    (NEXT_STEP) or refuses to step (DISABLED): ``done``, and none under SAME_STEP.
    """
    if mode != AutoresetMode.SAME_STEP:
        info.update({f"_{key}": mask for key in list(info)})
        return done
    if done.any():
        ended = np.flatnonzero(done)
        final_obs = np.full(len(done), None, dtype=object)
        final_obs[ended] = list(observations[ended])
        final_info = {**info, **{f"_{key}": done for key in info}}
        observations[ended] = restart(ended)
        info.update({f"_{key}": ~done for key in list(info)})
        info.update(final_obs=final_obs, _final_obs=done, final_info=final_info, _final_info=done)
    else:
        info.update({f"_{key}": mask for key in list(info)})
    return np.zeros_like(done)


#: The keys of a trajectory mapping (a scene's ``trajectory``, the gait's ``trajectory``).
TRAJECTORY_KEYS = ("axis", "alpha_start_deg", "alpha_end_deg", "alpha_step_deg")


def check_trajectory(spec: Mapping[str, Any]) -> Trajectory:
    """A :class:`Trajectory` from a mapping with :data:`TRAJECTORY_KEYS`: ``axis`` a finite
    non-zero 3-vector (any length), the alphas in [-180, 180] deg, start <= end, a step in
    (0, 360] deg, and at most :data:`MAX_POSES` poses."""
    if not isinstance(spec, Mapping):
        raise ValueError(f"scene 'trajectory' must be a mapping with keys {TRAJECTORY_KEYS}")
    for key in spec:
        if key not in TRAJECTORY_KEYS:
            raise ValueError(
                f"unknown trajectory key {key!r}; the trajectory keys are {TRAJECTORY_KEYS}"
            )
    axis = check_array("trajectory 'axis'", spec["axis"], (3,))  # Trajectory refuses zero
    start, end = (
        check_number(f"trajectory {key!r}", spec[key], *ALPHA_RANGE_DEG)
        for key in ("alpha_start_deg", "alpha_end_deg")
    )
    if end < start:
        raise ValueError(
            f"trajectory 'alpha_end_deg' ({end}) must be >= 'alpha_start_deg' ({start})"
        )
    step = check_number(
        "trajectory 'alpha_step_deg'", spec["alpha_step_deg"], 0.0, 360.0, open_low=True
    )
    check_pose_count("trajectory 'alpha_step_deg'", end - start, step)
    return Trajectory(tuple(axis), start, end, step)


def check_pose_count(name: str, span: float, step: float) -> int:
    """The pose count of a trajectory spanning ``span`` degrees in steps of ``step`` (as
    :attr:`Trajectory.alphas_deg`), at most :data:`MAX_POSES`."""
    ratio = span / step
    count = int(np.floor(ratio + 1e-9)) + 1 if ratio < MAX_POSES else MAX_POSES + 1
    if count > MAX_POSES:
        raise ValueError(
            f"{name}: a trajectory may have at most {MAX_POSES} poses, but {span:g} deg in"
            f" steps of {step:g} deg makes {np.floor(ratio + 1e-9) + 1:g}"
        )
    return count
