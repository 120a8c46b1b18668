"""Model description: YAML files -> typed model -> flat arrays for the kernels."""
