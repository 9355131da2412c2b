"""An alias of :mod:`grasp_env_agents.learning.policy` under its earlier path: a model saved by
an earlier version names its classes here (SB3 pickles a policy class by its import path)."""

from .learning.policy import ForceDirectionPolicy

__all__ = ["ForceDirectionPolicy"]
