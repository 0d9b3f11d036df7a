"""Semantic checks of an architecture beyond its schema.

Each rule yields :class:`~archself.findings.Finding` objects located at the
offending node. The rules:

* ``reference``: every name used (edges, configurations, actions, faults,
  constraints, objective) refers to a declared module or configuration;
* ``unknown-type``: every module ``type`` is registered (built-in or plugin);
* ``self-loop``, ``duplicate``: edges are proper and unique, action ids unique;
* ``weight``: W_ji ≥ 0 (Eq. 13);
* ``spectral-radius``, ``singular``: ρ(W) < ``runtime.max_spectral_radius`` < 1 so
  that I − Wᵀ is nonsingular and z = (I − Wᵀ)⁻¹ r is bounded (Eq. 13–14);
* ``signal``: an edge carries a signal its source outputs;
* ``port``: named ports (``from: module.port``) exist on the types, with "did you
  mean"; an edge names a signal (:mod:`archself.model.architecture`);
* ``incomplete``: in each configuration every active module receives its
  required inputs over active edges, the active modules are connected, and the
  modules ``runtime.objective`` reads are active; a configuration that fills
  none of the roles the initial configuration fills gets a warning;
* ``double-input``: no module receives the same signal (input port) over two active
  edges of one configuration (the executor would keep only one of them);
* ``algebraic-loop``: every cycle of active edges passes through a module
  without direct feedthrough (a plant, a delay), so the data flow can be ordered;
* ``module-constraint``: k_i ``requires``/``excludes`` hold in each configuration;
* ``budget``: each configuration satisfies C(a, θ, e) ≤ 0 (Eq. 27) — a warning;
* ``parameter``: required parameters are given, every parameter is one the type
  declares (when it declares them: ``RuntimeModule.parameters``),
  nominal values lie inside their spaces, and every number of a value (and the
  file's ``min``/``max``) lies in the range the type declares (``Param.min``/``max``);
* ``fault``: faults target modules whose type accepts that fault kind and signal,
  and that are in at least one configuration (else the fault never acts);
* ``work``: each scenario's run fits the caps of :mod:`archself.check.rules`:
  ``MAX_RUN_STEPS`` simulation steps, ``MAX_RUN_BYTES`` of recorded series,
  ``MAX_RUN_WORK`` module-steps with the rollouts and Lyapunov tests (:func:`run_estimate`);
* ``clock``: a scenario lasts at least one step; ``runtime.period_s`` and every period
  parameter of a type (``Param(period=True)``, a rate in Hz as its inverse) are at least
  ``runtime.step_s``;
* ``build``: on a file without other errors, each module's memory (its type's
  ``memory_estimate``) is under ``MAX_MODULE_BYTES`` and its type's ``check_params`` (by
  default: one module built) accepts its nominal values and every parameter update, so a
  shape error is a located finding, not a failure of the run;
* ``action``: actions lead to declared configurations, their kind matches the
  change, parameter updates name parameters of the module and stay in bounds;
  the module an action addresses is active where it applies (a warning);
* ``residual``: a residual names a signal the module's type publishes;
* ``initial``: at most one configuration is marked initial;
* ``subsystem``: subsystem modes name declared modules, each module in one mode of one
  subsystem; a composed configuration (``modes``) names declared subsystems and modes
  and lists none of their modules as its own;
* ``limits``: a module's ``constraints.blocks`` names declared actions (and has
  ``limits`` to be violated);
* ``stability``: with ``runtime.stability.verify`` warning or error (opt-in: it
  compiles the modules), every configuration's closed loop and every action's
  result pass Eq. 21 and the whole-loop check (:mod:`archself.check.stability`); judged
  only on a file without errors; with it off, an ``info`` finding says it was not checked.

The rules, the :class:`~archself.check.rules.Context` they share and :func:`check`,
which runs them in order, are in :mod:`archself.check.rules`; the whole-loop stability
check (it compiles the modules) in :mod:`archself.check.stability`. This package
re-exports ``check``, ``has_errors``, ``run_estimate`` and ``spectrum_summary``.
"""

from archself.check.rules import check, has_errors, run_estimate, spectrum_summary

__all__ = ["check", "has_errors", "run_estimate", "spectrum_summary"]
