"""An alias of :mod:`grasp_env_agents.learning.algorithms` under its earlier path: a model saved by
an earlier version names its classes here (SB3 pickles a policy class by its import path)."""

from .learning.algorithms import ForceDirectionSACPolicy, ForceDirectionTD3Policy

__all__ = ["ForceDirectionSACPolicy", "ForceDirectionTD3Policy"]
