"""A configuration compiled into a running system: the compiler, the synchronous data-flow
executor (step plan, health, faults, snapshots, linearization) and the objective error."""
