"""The closed loop as linear algebra: modules' linear models wired by the edges, discretized at
the step, assembled (dense or sparse), and their modes (eigenvalues, participation)."""
