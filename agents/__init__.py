"""The application layer: the paper's experiment, PPO training, evaluation, physics checks, CLI."""
