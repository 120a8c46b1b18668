"""Per-chain kinematics, closure residual and Jacobians, assembly."""
