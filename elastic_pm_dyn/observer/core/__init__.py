"""The filter core: the compiled kernels of the state and covariance (linearisation,
propagation, corrections), the per-period step live and offline (:mod:`.period`), the fixed
observer model, the sensor and disturbance models, and the observability analysis."""
