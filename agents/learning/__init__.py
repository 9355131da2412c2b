"""The learning stack: the policies and their grasp features, imitation of the minimax expert,
the algorithms, the environments' adapter, the baselines, and saving and safely loading models
and checkpoints."""
