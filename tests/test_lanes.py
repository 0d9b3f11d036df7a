"""The lane-batched executor (archself.lanes) against the per-run path."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from ruamel.yaml import YAML

from archself.errors import SimulationError
from archself.lanes import ALL, LaneNormals, LaneSystem, PerLane, row, simulate_lanes, stack
from archself.model.architecture import Architecture
from archself.resources import data_dir
from archself.sim.run import simulate


def _raw(name: str) -> dict:
    return YAML(typ="safe").load(data_dir("architectures") / f"{name}.yaml")


@pytest.fixture(scope="module")
def diffdrive_raw() -> dict:
    return _raw("diffdrive")


def _close(a, b, path="") -> None:
    """Equal structure and words; numbers within 1e-9 (the batched classes' last bits)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{k}]")
    elif isinstance(a, float) and not isinstance(a, bool):
        assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=path)
    else:
        assert a == b, path


def _same(lanes, runs, atol=1e-9) -> None:
    for got, want in zip(lanes, runs, strict=True):
        assert got.seed == want.seed and got.mode == want.mode == "fixed"
        assert set(got.series) == set(want.series)
        for key, val in want.series.items():
            assert_allclose(got.series[key], val, rtol=0, atol=atol, err_msg=key)
        for key, val in want.metrics.items():
            assert_allclose(got.metrics[key], val, rtol=0, atol=atol, err_msg=key)
        assert got.meta == want.meta


def test_lane_normals_are_the_per_run_draws_in_any_chunking() -> None:
    rngs = [np.random.default_rng(s) for s in range(4)]
    twins = [np.random.default_rng(s) for s in range(4)]
    z = LaneNormals(rngs, block=7)
    got = [[] for _ in range(4)]
    for k in (3, 2, 5, 1, 7):  # every lane, then only some lanes
        for i, v in enumerate(z.take(ALL, k)):
            got[i].extend(v)
        for i, v in zip((1, 3), z.take(np.array([1, 3]), k), strict=True):
            got[i].extend(v)
    for i in range(4):
        assert_array_equal(got[i], twins[i].standard_normal(len(got[i])))
    with pytest.raises(ValueError, match="exceed the block"):
        z.take(ALL, 8)


def test_lane_normals_of_a_shared_generator_are_each_lanes_own_stream() -> None:
    """Lanes that name one generator (a check's probe lanes) draw it once while they
    refill together; each lane still gets the per-run draws of its own copy, also after
    a refill of some lanes alone and at its exact state when pinned."""
    shared = np.random.default_rng(5)
    z = LaneNormals([shared, np.random.default_rng(9), shared, shared], block=6)
    seeds = (5, 9, 5, 5)
    got = [[] for _ in range(4)]
    for k in (4, 5, 3):  # every lane together: one stream drawn for lanes 0, 2 and 3
        for i, v in enumerate(z.take(ALL, k)):
            got[i].extend(v)
    assert z.rngs[2] is shared and z.rngs[3] is shared
    for i, v in zip((2, 3), z.take(np.array([2, 3]), 5), strict=True):  # a lone refill parts them
        got[i].extend(v)
    assert len({id(r) for r in z.rngs}) == 4
    for k in (6, 2):
        for i, v in enumerate(z.take(ALL, k)):
            got[i].extend(v)
    for i in range(4):
        assert_array_equal(got[i], np.random.default_rng(seeds[i]).standard_normal(len(got[i])))
        z.pin(i)
        twin = np.random.default_rng(seeds[i])
        twin.standard_normal(len(got[i]))
        assert z.rngs[i].bit_generator.state == twin.bit_generator.state
    z.unpin()


def test_row_and_stack_are_inverse_with_absent_lanes() -> None:
    values = [np.array([1.0, 2.0]), None, np.array([3.0, 4.0])]
    lane = stack(values)
    assert lane.shape == (3, 2) and np.isnan(lane[1]).all()
    assert [None if row(lane, j) is None else row(lane, j).tolist() for j in range(3)] == [
        [1.0, 2.0], None, [3.0, 4.0]
    ]
    assert stack([None, 2.0]).tolist()[1] == 2.0 and row(stack([None, 2.0]), 0) is None
    assert stack(["a", None]) == ["a", None]


@pytest.mark.parametrize("scenario", ["nominal", "valve_flicker"])
def test_process_plant_lanes_equal_the_per_run_runs(scenario) -> None:
    """The tank's batched types (archself_process.lanes_*): the per-run results, bit for bit."""
    arch = Architecture.model_validate(_raw("process_plant"))
    seeds = [3, 4, 5]
    lanes = simulate_lanes(arch, scenario, seeds)
    _same(lanes, [simulate(arch, scenario, seed=s) for s in seeds], atol=0.0)


def test_faults_edge_noise_and_latency_per_lane(diffdrive_raw) -> None:
    """Every fault kind, a noisy and a delayed edge, lanes of other parameters (a sweep)."""
    raw = copy.deepcopy(diffdrive_raw)
    for e in raw["edges"]:
        if e["from"] == "encoders" and e["to"] == "odometry":
            e["uncertainty"] = 0.02
        if e["from"] == "imu" and e["to"] == "odometry":
            e["latency_s"] = 0.1
            e["uncertainty"] = 0.001
    raw["scenarios"]["mix"] = {
        "duration_s": 30,
        "seed": 1,
        "faults": [
            {"module": "gps", "kind": "dropout", "onset_s": 4, "end_s": 9},
            {"module": "imu", "kind": "noise_increase", "onset_s": 2, "magnitude": 3.0,
             "signal": "heading"},
            {"module": "encoders", "kind": "stuck", "onset_s": 12, "end_s": 14},
            {"module": "imu", "kind": "nan", "onset_s": 20, "end_s": 21, "signal": "heading"},
            {"module": "wheel_left", "kind": "effectiveness_loss", "onset_s": 5,
             "magnitude": 0.3},
            {"module": "imu", "kind": "bias_drift", "onset_s": 3, "magnitude": 0.01,
             "signal": "heading"},
            {"module": "encoders", "kind": "bias", "onset_s": 25, "magnitude": 0.2},
        ],
    }
    archs = []
    for noise in (0.05, 0.2, 0.1):
        r = copy.deepcopy(raw)
        r["modules"]["encoders"]["params"]["noise_rad_s"]["value"] = noise
        archs.append(Architecture.model_validate(r))
    seeds = [11, 12, 13]
    for conf in ("a1", "a2"):
        lanes = simulate_lanes(archs, "mix", seeds, configuration=conf)
        runs = [
            simulate(a, "mix", seed=s, configuration=conf)
            for a, s in zip(archs, seeds, strict=True)
        ]
        _same(lanes, runs)
        assert lanes[0].metrics["max_error"] != lanes[1].metrics["max_error"]


def test_a_module_that_raises_holds_its_last_outputs_in_that_lane(diffdrive_raw) -> None:
    from archself.system.live import compile_system

    arch = Architecture.model_validate(diffdrive_raw)
    systems = [compile_system(arch, "a1", seed=s, scenario="nominal") for s in (1, 2)]
    lanes = LaneSystem(systems)
    # the odometry lane by lane (whatever the pack batches), so one lane can fail alone
    lanes.modules["odometry"] = PerLane([s._module("odometry") for s in systems])
    for _ in range(3):
        lanes.step()
    before = lanes.signal("odometry", "pose_estimate").copy()

    def boom(*_a, **_k):
        raise KeyError("x")

    systems[1]._module("odometry").step = boom
    lanes.step()
    after = lanes.signal("odometry", "pose_estimate")
    assert_array_equal(after[1], before[1])  # held
    assert not np.array_equal(after[0], before[0])
    assert lanes.failed["odometry"].tolist() == [1]
    assert [lanes.reasons(i)["odometry"] for i in (0, 1)] == [None, "raised KeyError"]
    lanes.step()  # the failure is reported each step it lasts, then cleared
    assert lanes.failed["odometry"].tolist() == [1]
    del systems[1]._module("odometry").step
    lanes.step()  # a publishing with nothing to judge settles the lane back
    assert "odometry" not in lanes.failed
    assert lanes.available(1)["odometry"] and lanes.reasons(1)["odometry"] is None


def test_lanes_in_different_configurations_run_as_groups(diffdrive_raw) -> None:
    """Two groups (a1 and a3) in one lane system: each lane is its per-run run."""
    from archself.system.live import compile_system

    arch = Architecture.model_validate(diffdrive_raw)
    confs = ["a1", "a3", "a1", "a3"]
    systems = [compile_system(arch, c, seed=5 + i, scenario="actuator_fault")
               for i, c in enumerate(confs)]
    twins = [compile_system(arch, c, seed=5 + i, scenario="actuator_fault")
             for i, c in enumerate(confs)]
    lanes = LaneSystem(systems)
    assert {c: g.tolist() for c, g in lanes.groups.items()} == {"a1": [0, 2], "a3": [1, 3]}
    for _ in range(600):
        lanes.step()
        for tw in twins:
            tw.step()
    pose = lanes.signal("chassis", "pose")
    for i, tw in enumerate(twins):
        assert_allclose(pose[i], tw.signal("chassis.pose"), rtol=0, atol=1e-9)
        assert lanes.available(i) == tw.available()


def test_health_per_lane_is_the_per_run_health(diffdrive_raw) -> None:
    """Silence (GPS dropout), stale values (stuck encoders), non-finite output (NaN fault),
    lost inputs downstream: the reason of every module in every lane at every step."""
    from archself.system.live import compile_system

    raw = copy.deepcopy(diffdrive_raw)
    raw["scenarios"]["sick"] = {
        "duration_s": 20,
        "seed": 1,
        "faults": [
            {"module": "gps", "kind": "dropout", "onset_s": 3, "end_s": 8},
            {"module": "encoders", "kind": "stuck", "onset_s": 9, "end_s": 11},
            {"module": "imu", "kind": "nan", "onset_s": 12, "end_s": 12.5, "signal": "heading"},
            {"module": "imu", "kind": "dropout", "onset_s": 15, "end_s": 16,
             "signal": "heading"},
        ],
    }
    arch = Architecture.model_validate(raw)
    confs = ["a3", "a1", "a3"]
    systems = [compile_system(arch, c, seed=i, scenario="sick") for i, c in enumerate(confs)]
    twins = [compile_system(arch, c, seed=i, scenario="sick") for i, c in enumerate(confs)]
    lanes = LaneSystem(systems)
    seen = set()
    for _ in range(400):
        lanes.step()
        for i, tw in enumerate(twins):
            tw.step()
            want = tw.health()
            assert lanes.reasons(i) == want, (lanes.t, i)
            seen.update(r.split()[0] for r in want.values() if r)
    assert {"silent", "stale", "non-finite", "lost"} <= seen


def test_lanes_of_different_structure_are_refused(diffdrive_raw) -> None:
    from archself.system.live import compile_system

    arch = Architecture.model_validate(diffdrive_raw)
    raw = copy.deepcopy(diffdrive_raw)
    raw["runtime"]["step_s"] = 0.1
    other = Architecture.model_validate(raw)
    with pytest.raises(SimulationError, match="share the architecture"):
        LaneSystem([compile_system(arch, "a1", seed=1), compile_system(other, "a1", seed=1)])
    with pytest.raises(SimulationError, match="unknown scenario"):
        simulate_lanes(arch, "nope", [1])
    with pytest.raises(SimulationError, match="one seed per lane"):
        simulate_lanes([arch, arch], "nominal", [1])


def _rows(path) -> list[dict]:
    from archself.campaign.results import read_results

    table, _ = read_results(path)
    rows = sorted(table.to_pylist(), key=lambda r: r["run_id"])
    for r in rows:
        r.pop("trace", None)
    return rows


@pytest.mark.parametrize("sweep", ["scenarios.valve_loss.faults[0].magnitude=0.3,0.45",
                                   "runtime.step_s=0.2,0.25"])
def test_a_campaign_of_lanes_writes_the_rows_of_the_per_run_campaign(tmp_path, sweep) -> None:
    """Fixed and adaptive runs in batches of 8 give the rows of --lanes 1; so does a sweep
    whose points cannot share lanes (another step: the units
    fall back to single runs)."""
    from archself.campaign import plan_campaign, run_campaign
    from archself.campaign.sweep import parse_sweep

    path = data_dir("architectures") / "process_plant.yaml"
    jobs, meta = plan_campaign(path, ["nominal", "valve_loss"], 2, [parse_sweep(sweep)])
    assert meta["lane_types"] is True  # the tank's types are batched: lanes by default
    rows = {}
    for lanes in (1, 8):
        out = tmp_path / f"r{lanes}.parquet"
        run_campaign(jobs, meta, out, workers=1, lanes=lanes)
        rows[lanes] = _rows(out)
    assert len(rows[1]) == len(rows[8]) == 16 and any(r["n_switches"] for r in rows[1])
    for got, want in zip(rows[8], rows[1], strict=True):
        _close(got, want)


def test_files_whose_types_are_all_batched_go_in_lanes_by_default() -> None:
    from archself.lanes.batching import batched_types
    from archself.model.loader import load_architecture

    found = {n: batched_types(load_architecture(data_dir("architectures") / f"{n}.yaml").arch)
             for n in ("diffdrive", "process_plant", "motor_drive")}
    assert found == {"diffdrive": True, "process_plant": True, "motor_drive": True}


def test_lane_units_group_fixed_runs_of_one_scenario_in_order() -> None:
    from archself.campaign.plan import default_lanes, lane_units
    from archself.campaign.worker import Job

    def job(i, mode, sc="s"):
        return Job(arch_text="", arch_digest="d", file="f", scenario=sc, replicate=i, seed=i,
                   run_id=str(i), mode=mode)

    jobs = [job(i, "fixed", "ab"[i % 2]) for i in range(7)] + [job(7, "adaptive")]
    units = lane_units(jobs, 2)
    assert [[j.run_id for j in u] for u in units] == [
        ["0", "2"], ["1", "3"], ["4", "6"], ["5"], ["7"]
    ]
    assert [len(u) for u in lane_units(jobs, 1)] == [1] * 8
    assert default_lanes(jobs, 2) == 4 and default_lanes(jobs * 100, 2) == 256
    assert default_lanes(jobs * 100, 2, steps_per_run=8000, memory=2**30) == 32
    assert default_lanes([job(0, "adaptive")], 2) == 1


def test_lane_normals_give_the_exact_per_run_stream_state() -> None:
    rngs = [np.random.default_rng(s) for s in range(3)]
    z = LaneNormals(rngs, block=8)
    used = [0, 0, 0]
    for k, lanes in ((3, ALL), (5, np.array([0, 2])), (7, ALL), (2, np.array([1])), (6, ALL)):
        z.take(lanes, k)
        for i in (range(3) if isinstance(lanes, slice) else lanes):
            used[i] += k
    for i in range(3):
        twin = np.random.default_rng(i)
        twin.standard_normal(used[i])
        z.pin(i)
        assert_array_equal(rngs[i].standard_normal(4), twin.standard_normal(4))
    z.unpin()
    more = z.take(ALL, 3)  # the buffer goes on where it was
    for i in range(3):
        twin = np.random.default_rng(i)
        assert_array_equal(more[i], twin.standard_normal(used[i] + 3)[-3:])


@pytest.mark.parametrize("scenario", ["gps_dropout", "cascading"])
def test_adaptive_lanes_make_the_per_run_decisions(diffdrive_raw, scenario) -> None:
    """A MAPE-K loop per lane: the same switches, decision logs and series as per run
    (the Plan's rollouts see the lane materialized: states, streams, latency lines)."""
    from archself.runtime import MapeK

    arch = Architecture.model_validate(diffdrive_raw)
    seeds = [1, 4]
    lanes = simulate_lanes(arch, scenario, seeds, adapt=True)
    for got, seed in zip(lanes, seeds, strict=True):
        want = simulate(arch, scenario, seed=seed, adapt=MapeK(arch))
        assert got.mode == "adaptive" and len(want.switches) >= 2
        assert got.switches == want.switches
        assert got.final_configuration == want.final_configuration
        assert len(got.decisions) == len(want.decisions)
        for a, b in zip(got.decisions, want.decisions, strict=True):
            _close(a.to_dict(), b.to_dict())
        for key, val in want.series.items():
            assert_allclose(got.series[key], val, rtol=0, atol=1e-9, err_msg=key)


def test_sweep_lanes_of_another_acceptable_j_record_their_own_j_ref() -> None:
    """Sweep points that differ in ``runtime.objective.acceptable`` share a configuration
    group: each lane's records hold its own J_ref (and r = J_ref − J_obs), as per run."""
    from archself.runtime import MapeK

    a = Architecture.model_validate(_raw("process_plant"))
    b = a.model_copy(deep=True)
    b.runtime.objective.acceptable = 0.5 * a.runtime.objective.acceptable
    lanes = simulate_lanes([a, b], "level_drift", [3, 3], adapt=True)
    for arch, got in zip((a, b), lanes, strict=True):
        want = simulate(arch, "level_drift", seed=3, adapt=MapeK(arch))
        assert {d.j_ref for d in got.decisions} == {arch.runtime.objective.acceptable}
        assert [d.to_dict() for d in got.decisions] == [d.to_dict() for d in want.decisions]


def test_calibration_runs_in_lanes_record_the_per_run_residuals() -> None:
    """calibrate's runs batched (one unit of sweep points and seeds, 2 each): the same recorded
    filtered residuals, unusable flags and times as run by run."""
    from archself.calibration import runs as R
    from archself.campaign.sweep import parse_sweep

    path = data_dir("architectures") / "process_plant.yaml"
    jobs = R.plan_runs(path.read_text(), path.name, ["nominal"], ["p1"], R.seeds_from(0, 0, 4),
                       envelope=[parse_sweep("modules.level_a.params.noise_m.value=0.002,0.004")])
    units = R.calibration_units(jobs, 1)
    assert [len(u) for u in units] == [4]
    got = R.run_calibration_unit(units[0])
    for job, lane in zip(jobs, got, strict=True):
        want = R.run_calibration_job(job)
        assert lane["error"] is None and lane["seed"] == want["seed"]
        assert lane["x"].shape == want["x"].shape and lane["x"].any()
        assert_allclose(lane["x"], want["x"], rtol=0, atol=1e-12)
        assert_array_equal(lane["forced"], want["forced"])
        assert_array_equal(lane["t"], want["t"])


@pytest.mark.parametrize(("name", "scenario"), [("motor_drive", "tacho_drift"),
                                                ("process_plant", "drift_then_valve")])
def test_every_shipped_architecture_runs_in_lanes_as_per_run(name, scenario) -> None:
    """The generic blocks (a summing junction's multi-edge input, LTI plants) and the tank's
    types, batched, fixed and adaptive: the per-run runs."""
    from archself.runtime import MapeK

    arch = Architecture.model_validate(_raw(name))
    seeds = [1, 2]
    _same(simulate_lanes(arch, scenario, seeds), [simulate(arch, scenario, seed=s) for s in seeds])
    lanes = simulate_lanes(arch, scenario, seeds, adapt=True)
    for got, seed in zip(lanes, seeds, strict=True):
        want = simulate(arch, scenario, seed=seed, adapt=MapeK(arch))
        assert got.switches == want.switches and want.switches
        assert_allclose(got.series["J"], want.series["J"], rtol=0, atol=1e-9)


def test_quiet_lanes_record_what_the_per_lane_call_records(diffdrive_raw, monkeypatch) -> None:
    """Lanes without a candidate and nothing pending skip ``MapeK.__call__``: those with
    r = 0 recorded from their group's numbers (``MapeK.quiet_zeros``, no Observation
    made), those with a residual by ``MapeK.quiet``. The decision logs, switches and J
    equal those of every lane's loop called every cycle."""
    from archself.runtime import MapeK

    class Called(MapeK):  # a subclass: simulate_lanes calls it every cycle
        pass

    arch = Architecture.model_validate(diffdrive_raw)
    seeds = [2, 5]
    full = simulate_lanes(arch, "imu_drift", seeds, adapt=Called)
    taken: dict[str, list[bool]] = {"quiet": [], "quiet_zeros": []}

    def counting(name: str):
        real = getattr(MapeK, name)

        def counted(self, *args):
            taken[name].append(real(self, *args))
            return taken[name][-1]

        return counted

    for name in taken:
        monkeypatch.setattr(MapeK, name, counting(name))
    got = simulate_lanes(arch, "imu_drift", seeds, adapt=True)
    n_cycles = sum(len(r.decisions) for r in got)
    assert sum(taken["quiet_zeros"]) > 0.8 * n_cycles  # most cycles: r = 0, no Observation
    assert sum(taken["quiet"]) > 0  # a residual without a candidate
    assert sum(taken["quiet_zeros"]) + sum(taken["quiet"]) > 0.9 * n_cycles
    for a, b in zip(got, full, strict=True):
        assert a.switches == b.switches and len(a.switches) == 1
        assert [d.to_dict() for d in a.decisions] == [d.to_dict() for d in b.decisions]
        assert_array_equal(a.series["J"], b.series["J"])


def test_quiet_zeros_records_what_quiet_records(diffdrive_raw) -> None:
    """``MapeK.quiet_zeros`` appends the record ``MapeK.quiet`` appends for an observation
    with r = 0 and no κ finding (its zeros shared between records, read-only), and
    records nothing where ``quiet`` would refuse, nor with ``runtime.online`` on."""
    from archself.runtime import MapeK
    from archself.runtime.planner import HysteresisSelector, ThresholdSelector
    from archself.system.live import compile_system

    arch = Architecture.model_validate(diffdrive_raw)
    loop, ref = MapeK(arch), MapeK(arch)
    system = compile_system(arch, arch.initial_configuration(), seed=1)
    for step in range(1, 1000):  # until every residual signal is usable (the GLR's window)
        system.step()
        if step % 10 == 0:
            obs = ref.monitor.observe(system, ref.knowledge.active)
            loop.monitor.observe(system, loop.knowledge.active)
            if not obs.kappa.findings():
                break
    for lp in (loop, ref):
        lp.knowledge.sync(system)
    assert not obs.r.any() and not obs.kappa.findings()
    conf, active, t = system.configuration, system.active, float(system.t)
    for _ in range(2):
        assert loop.quiet_zeros(conf, active, t, obs.j_obs, obs.j_ref)
        assert ref.quiet(system, obs)
    assert [d.to_dict() for d in loop.decisions] == [d.to_dict() for d in ref.decisions]
    assert loop.cycle == ref.cycle == 2 and loop.decisions[1].cycle == 1
    r0, r1 = loop.decisions[0].r, loop.decisions[1].r
    assert r0 is r1 and len(r0) == len(loop.knowledge.active_names)
    with pytest.raises(ValueError):
        r0._values[0] = 1.0  # shared: never written
    other = next(c for c in arch.configurations if c != conf)
    refused = [(other, active), (conf, frozenset(active) - {next(iter(active))})]
    for c, a in refused:
        assert not loop.quiet_zeros(c, a, t, obs.j_obs, obs.j_ref)
    h = loop.selector = HysteresisSelector(on=0.6, off=0.0)
    h.members = {"imu"}
    assert not loop.quiet_zeros(conf, active, t, obs.j_obs, obs.j_ref)
    loop.selector = ThresholdSelector(0.0)  # selects every module on zeros
    assert not loop.quiet_zeros(conf, active, t, obs.j_obs, obs.j_ref)
    loop.selector = ThresholdSelector(0.5)
    loop.online = object()  # type: ignore[assignment]  # online reads the observation
    assert not loop.quiet_zeros(conf, active, t, obs.j_obs, obs.j_ref)
    assert len(loop.decisions) == 2


def test_quiet_refuses_a_cycle_with_anything_to_analyze(diffdrive_raw) -> None:
    """``MapeK.quiet`` records nothing (False) with a residual, a selector that selects on
    zeros or keeps members, or a configuration the Knowledge has not adopted."""
    from archself.runtime import MapeK
    from archself.runtime.planner import HysteresisSelector, ThresholdSelector
    from archself.system.live import compile_system

    arch = Architecture.model_validate(diffdrive_raw)
    loop = MapeK(arch)
    system = compile_system(arch, arch.initial_configuration(), seed=1)
    obs = loop.monitor.observe(system, loop.knowledge.active)
    loop.knowledge.sync(system)
    assert not obs.r.any()
    assert loop.quiet(system, obs) and len(loop.decisions) == 1 and loop.cycle == 1
    want = MapeK(arch)
    want(system, observation=obs)
    assert loop.decisions[0].to_dict() == want.decisions[0].to_dict()
    r = obs.r.copy()
    r[0] = 1.0
    hot = dataclasses.replace(obs, r=r)
    for o, sel in ((hot, ThresholdSelector(0.5)), (obs, ThresholdSelector(0.0))):
        loop.selector = sel
        assert not loop.quiet(system, o)
    # a residual without a candidate: Analyze made and recorded as the call records it
    for lp in (loop, want):
        lp.selector = ThresholdSelector(1e9)
    assert loop.quiet(system, hot) and len(loop.decisions) == 2
    want(system, observation=hot)
    got, ref = loop.decisions[1].to_dict(), want.decisions[1].to_dict()
    assert got == ref and ref["z"] and max(ref["source"].values()) > 0.5
    # with a candidate: refused, and the call that follows reuses that Analyze (no second
    # Analyze: the selector, which may keep state, is asked once a cycle)
    loop.selector = ThresholdSelector(0.5)
    assert not loop.quiet(system, hot)
    asked = []
    loop._analyze = lambda *a: asked.append(a)  # type: ignore[method-assign]
    loop(system, observation=hot)
    del loop._analyze
    assert not asked and loop.decisions[2].candidates and len(loop.decisions) == 3
    h = loop.selector = HysteresisSelector(on=0.6, off=0.0)
    h.members = {"imu"}
    assert not loop.quiet(system, obs)
    h.members = set()
    assert loop.quiet(system, obs)
    system.apply_configuration(next(c for c in arch.configurations if c != system.configuration))
    assert not loop.quiet(system, obs) and len(loop.decisions) == 4
