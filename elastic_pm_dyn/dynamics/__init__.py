"""Direct and inverse dynamics: multipliers, compact Lagrange-D'Alembert, SCDD."""
