"""Large generated architectures: the generate command, and z on a 10^4-module graph.

The influence solve with a reused sparse factorization (block-triangular order,
archself.runtime.influence) is checked against a direct sparse solve.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
from typer.testing import CliRunner

from archself.cli import app
from archself.model.generate import generate_architecture
from archself.runtime.influence import InfluenceSolver, spectral_radius, weight_matrix

_EDGE = re.compile(r'\{"from": "(m\d+)", "to": "(m\d+)", "weight": ([0-9.eE+-]+)')


def _graph(n: int, seed: int = 1, feedback: int = 0) -> tuple[list[str], list]:
    text = generate_architecture(n, seed=seed, feedback=feedback)
    edges = [(a, b, float(w)) for a, b, w in _EDGE.findall(text)]
    return [f"m{i}" for i in range(n)], edges


def _direct(W: scipy.sparse.spmatrix, r: np.ndarray) -> np.ndarray:
    n = W.shape[0]
    M = (scipy.sparse.identity(n, format="csc") - scipy.sparse.csc_matrix(W).T).tocsc()
    return scipy.sparse.linalg.spsolve(M, r)


@pytest.mark.parametrize("shuffle", [False, True])
def test_influence_on_10k_dag_matches_direct_solve(shuffle: bool) -> None:
    names, edges = _graph(10_000, feedback=0)
    if shuffle:  # a file whose modules are not in topological order
        names = list(np.random.default_rng(3).permutation(names))
    W = weight_matrix(names, edges)
    assert W.nnz > 10_000
    solver = InfluenceSolver()
    assert solver.set_matrix(W, key="w")
    rng = np.random.default_rng(0)
    for _ in range(3):  # the factorization is reused while W is unchanged
        r = rng.random(len(names))
        np.testing.assert_allclose(solver.solve(r), _direct(W, r), rtol=1e-10, atol=1e-12)
    assert not solver.set_matrix(W, key="w")
    assert solver.factorizations == 1


def test_influence_with_cycles_matches_direct_solve() -> None:
    """Cyclic blocks (strong components) inside a large DAG are factorized correctly."""
    names, edges = _graph(2_000)
    rng = np.random.default_rng(5)
    # close cycles: backward edges along existing forward edges
    for a, b, _w in [edges[i] for i in rng.choice(len(edges), size=40, replace=False)]:
        edges.append((b, a, 0.05))
    names = list(rng.permutation(names))
    W = weight_matrix(names, edges)
    rho = spectral_radius(W)
    assert 0 < rho < 1
    solver = InfluenceSolver(dense_max=0)
    solver.set_matrix(W)
    r = rng.random(len(names))
    np.testing.assert_allclose(solver.solve(r), _direct(W, r), rtol=1e-10, atol=1e-12)


def test_generate_command(tmp_path: Path) -> None:
    out = tmp_path / "g.yaml"
    res = CliRunner().invoke(
        app, ["generate", "300", "-o", str(out), "--seed", "2", "--feedback", "3"]
    )
    assert res.exit_code == 0, res.output
    assert out.read_text(encoding="utf-8") == generate_architecture(300, seed=2, feedback=3)
    res = CliRunner().invoke(app, ["validate", str(out)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["generate", "5"])
    assert res.exit_code == 0 and res.stdout.startswith("# yaml-language-server")
    res = CliRunner().invoke(app, ["generate", "1"])
    assert res.exit_code == 2
    res = CliRunner().invoke(app, ["generate", "5", "-o", str(tmp_path / "no" / "x.yaml")])
    assert res.exit_code == 1 and "does not exist" in res.stderr


@pytest.mark.parametrize("args", [["99999999999999999999", "--yes"],
                                  ["5", "--feedback", "1000000000", "--yes"]])
def test_generate_past_the_hard_cap_is_one_line_even_with_yes(args: list[str]) -> None:
    # N > 2**64 was `internal error: TypeError` (np.sqrt), 10^9 feedback edges a hang
    res = CliRunner().invoke(app, ["generate", *args])
    assert res.exit_code == 1 and "hard cap" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_one_mapek_cycle_on_generated_1k() -> None:
    """Load → compile → one MAPE-K cycle on a generated 10^3-module architecture."""
    from archself.model.loader import load_text
    from archself.runtime import MapeK
    from archself.system.live import compile_system

    arch = load_text(generate_architecture(1_000, seed=4)).arch
    system = compile_system(arch, arch.initial_configuration(), seed=0)
    system.step()
    loop = MapeK(arch)
    assert loop(system) == []
    rec = loop.decisions[-1]
    assert len(rec.z) == 1_000
    system.step()
    loop(system)
    k = loop.knowledge
    if not any(loop.decisions[-1].r.values()):  # a quiet cycle: z = 0 without a solve
        assert k.solver.factorizations == 0
        r = np.zeros(len(k.names))
        r[k.active_index[0]] = 1.0
        k.influence(r)
    assert k.solver.factorizations == 1
    z = k.influence(np.ones(len(k.names)))
    assert k.solver.factorizations == 1  # W unchanged: factorization reused
    assert np.all(z >= 1.0 - 1e-12)  # W ≥ 0: each z_i is at least its own r_i
