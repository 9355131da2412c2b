"""The training configs shipped with the package (YAML; `grasp-env train --config NAME`)."""
