"""FPMI-preserving stabilisation (thesis ch. 9): first-person motion structure, the objective and
its optimisation, and rendering of the stabilised video."""
