"""The runs of ``archself identify``: one job per (configuration, seed, perturbation).

:class:`IdJob` is one fault-free run, unperturbed or with a small fault on one
module from t = 0; :func:`run_identify_job` runs it in a campaign worker (the
architecture parsed once per process) and returns the time-averaged filtered
residual signals after the settling time. The jobs go to the campaign executors
through :func:`archself.calibration.runs.run_on_executor`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from archself.calibration.identify_results import IdentifyError
from archself.campaign.worker import RunJob, run_error

__all__ = ["IdJob", "run_identify_job"]


@dataclass(frozen=True, kw_only=True)
class IdJob(RunJob):
    """One run: (configuration, seed), unperturbed or with one perturbation
    (:class:`~archself.campaign.worker.RunJob` and the following).

    ``perturb`` is ``(module, kind, magnitude)`` or None for the nominal run.
    """

    configuration: str
    perturb: tuple[str, str, float] | None
    settle_s: float


def run_identify_job(job: IdJob) -> dict[str, Any]:
    """Run one job; never raises for a failed run.

    Returns
    -------
    dict
        ``configuration``, ``replicate``, ``seed``, ``experiment`` (the perturbed
        module or None), ``mean`` (time-averaged |s̄| per residual module after
        ``settle_s``, float64, in the file's module order), ``error``.
    """
    from archself.calibration.runs import Recorder
    from archself.model.architecture import Fault
    from archself.sim.run import simulate

    out: dict[str, Any] = {
        "configuration": job.configuration,
        "replicate": job.replicate,
        "seed": job.seed,
        "experiment": job.perturb[0] if job.perturb else None,
        "error": None,
    }
    try:
        arch = job.architecture().model_copy(deep=True)
        if job.perturb is not None:
            module, kind, magnitude = job.perturb
            arch.scenarios[job.scenario].faults.append(
                Fault.model_validate(
                    {"module": module, "kind": kind, "onset_s": 0.0, "magnitude": magnitude}
                )
            )
        rec = Recorder(arch)
        simulate(arch, job.scenario, configuration=job.configuration, seed=job.seed, adapt=rec)
        got = rec.arrays()
        keep = got["t"] >= job.settle_s - 1e-9
        if not keep.any():
            raise IdentifyError(f"no sample after the settling time {job.settle_s:g} s")
        out["mean"] = got["x"][keep].mean(axis=0)
    except Exception as exc:  # noqa: BLE001 - a failed run is reported, not fatal
        out["error"] = run_error(exc)
    return out

