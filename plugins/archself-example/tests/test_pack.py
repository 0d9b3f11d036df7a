"""The example plugin proves its types as a third-party pack would: archself.testing.check_pack."""

from pathlib import Path

from archself.testing import check_pack

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "tank_with_plugin.yaml"


def test_lanes_equal_per_run_runs() -> None:
    """example.p_level has no batched class: it runs lane by lane (PerLane), equal by contract."""
    report = check_pack(EXAMPLE, seeds=(1, 2), duration_s=30.0)
    assert report.ok and report.runs > 0
    assert report.types["example.p_level"] == "PerLane"
