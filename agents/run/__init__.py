"""A training run's folder: its layout, its config (the schema and the YAML loader) and its
learning curve."""
