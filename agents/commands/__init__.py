"""The ``grasp-env`` sub-commands: one module a command (``add_arguments(parser)`` and
``run(args) -> int``), read by :mod:`grasp_env_agents.cli`, which imports only the chosen one."""
