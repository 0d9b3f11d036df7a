"""The compiler: an architecture and a configuration → a running :class:`LiveSystem`.

:func:`compile_system` binds each module's nominal parameters, instantiates its
type through :mod:`archself.registry`, wires the modules along the active edges
(the executor precomputes the routing) and installs the scenario's faults.
Modules of other configurations are instantiated on demand when the runtime
switches to them (:meth:`LiveSystem.apply_configuration`).

Examples
--------
>>> from archself.system.compiler import compile_system
>>> from ruamel.yaml import YAML
>>> from archself.model.architecture import Architecture
>>> from archself.resources import data_dir
>>> raw = YAML(typ="safe").load(data_dir("architectures") / "diffdrive.yaml")
>>> arch = Architecture.model_validate(raw)
>>> sys_ = compile_system(arch, "a1", seed=1, scenario="nominal")
>>> sys_.step(); round(sys_.t, 2)
0.05
"""

from __future__ import annotations

from functools import partial

from archself import registry
from archself.errors import ArchselfError, CompileError, SimulationError
from archself.model.architecture import Architecture, Scenario
from archself.modules.base import RuntimeModule
from archself.system.executor import LiveSystem
from archself.system.faults import FaultInjector, default_signal
from archself.system.streams import module_rng

__all__ = ["compile_system", "build_module"]


def build_module(arch: Architecture, name: str, seed: int) -> RuntimeModule:
    """Instantiate module ``name`` with its nominal parameters and own random stream.

    Raises
    ------
    CompileError
        If the module is unknown or its type refuses the parameters.
    RegistryError
        If its type is not registered.
    """
    spec = arch.modules.get(name)
    if spec is None:
        raise CompileError(f"unknown module {name!r}")
    cls = registry.get(spec.type)
    try:
        params = {k: p.value for k, p in spec.params.items()}  # the nominal values
        return cls(name, params, module_rng(seed, name))
    except ArchselfError:
        raise
    except Exception as exc:
        raise CompileError(f"module {name!r} ({spec.type}) could not be built: {exc}") from exc


def compile_system(
    arch: Architecture,
    configuration: str | None = None,
    *,
    seed: int,
    scenario: str | Scenario | None = None,
) -> LiveSystem:
    """Build the live system of ``configuration`` with the faults of ``scenario``.

    Parameters
    ----------
    arch : Architecture
        A validated architecture.
    configuration : str, optional
        Configuration to start in (default: the file's initial one).
    seed : int
        Seed of every random stream (modules, edges, faults).
    scenario : str or Scenario, optional
        Scenario whose faults are installed (None: no faults).

    Returns
    -------
    LiveSystem

    Raises
    ------
    CompileError
        Unknown configuration or module, a fault on a module that does not
        accept its kind or lacks the signal, an algebraic loop.
    SimulationError
        Unknown scenario.
    """
    configuration = configuration or arch.initial_configuration()
    if configuration not in arch.configurations:
        known = ", ".join(arch.configurations)
        raise CompileError(f"unknown configuration {configuration!r}; known: {known}")
    factory = partial(build_module, arch, seed=int(seed))  # snapshots share it
    sc = arch.scenarios.get(scenario) if isinstance(scenario, str) else scenario
    if sc is None and scenario is not None:
        known = ", ".join(arch.scenarios) or "none"
        raise SimulationError(f"unknown scenario {scenario!r}; known: {known}")
    faults: dict[str, list[tuple[str, FaultInjector]]] = {}
    for i, f in enumerate(sc.faults if sc is not None else ()):
        if f.module not in arch.modules:
            raise CompileError(f"fault {i} targets unknown module {f.module!r}")
        cls = registry.get(arch.modules[f.module].type)
        if f.kind not in cls.fault_kinds:
            raise CompileError(
                f"fault {i}: module {f.module!r} ({cls.type_key}) does not take "
                f"{f.kind!r} faults (it takes: {', '.join(sorted(cls.fault_kinds)) or 'none'})"
            )
        probe = build_module(arch, f.module, seed)
        signal = f.signal or default_signal(probe)
        if signal is None or signal not in cls.outputs:
            raise CompileError(
                f"fault {i}: module {f.module!r} has no output {signal!r} "
                f"(outputs: {', '.join(cls.outputs)})"
            )
        base = (getattr(probe, "noise_levels", None) or {}).get(signal)
        inj = FaultInjector(
            f.kind,
            onset_s=f.onset_s,
            magnitude=f.magnitude,
            end_s=f.end_s,
            signal=signal,
            rng=module_rng(seed, f"fault:{f.module}:{i}"),
            base_noise=base,
        )
        faults.setdefault(f.module, []).append((signal, inj))
    return LiveSystem(arch, configuration, factory, seed=int(seed), faults=faults)
