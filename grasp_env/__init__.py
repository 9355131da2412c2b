"""grasp-env: grip-force optimisation of multi-fingered grasps as Gymnasium environments."""

__version__ = "0.1.0"
