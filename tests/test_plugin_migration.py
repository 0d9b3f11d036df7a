"""A plugin of the API before ``parameters`` (``optional_params``) is converted, not unchecked.

Issue 40: such a type ran, but ``validate`` checked none of its parameters (a typo
``noise_k`` validated and the type's default was used). :func:`archself.registry.migrate`
turns its names into ``parameters``, warns once, and ``validate`` says it (docs/plugins.md,
"Migrating from optional_params").
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from archself import registry
from archself.check import check
from archself.model.loader import load_text
from archself_diffdrive.physical import Imu

from conftest import FIXTURES

MINIMAL = (FIXTURES / "valid" / "minimal.yaml").read_text(encoding="utf-8")
KEY = "test.old_imu"


class OldImu(Imu):
    """The compass as a plugin of a few weeks ago wrote it: names only, defaults in the code."""

    parameters = None
    optional_params = ("noise_rad", "bias_rad")

    def configure(self) -> None:
        self.noise = float(self.params.get("noise_rad", 0.02))
        self.bias = float(self.params.get("bias_rad", 0.0))


@pytest.fixture
def old_type():
    with pytest.warns(FutureWarning, match="declares optional_params") as caught:
        registry.add(KEY, OldImu)
    yield caught
    registry.unregister(KEY)
    registry.LEGACY.pop(KEY, None)
    OldImu.parameters = None
    del OldImu.default_params


def _findings(text: str) -> list:
    return check(load_text(text, "t.yaml"))


def test_an_old_declaration_is_converted_and_warns_once(old_type) -> None:
    assert len(old_type) == 1
    assert "docs/plugins.md, 'Migrating from optional_params'" in str(old_type[0].message)
    assert sorted(OldImu.parameters) == ["bias_rad", "noise_rad"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second registration does not warn again
        registry.unregister(KEY)
        registry.add(KEY, OldImu)
    m = OldImu("compass", {}, np.random.default_rng(0))
    assert (m.noise, m.bias, m.params) == (0.02, 0.0, {})  # its own defaults still hold


def test_validate_checks_an_old_plugins_parameters_again(old_type) -> None:
    text = MINIMAL.replace("type: sensor.imu}",
                           f"type: {KEY}, params: {{noise_rd: {{value: 0.5}}}}}}")
    found = _findings(text)
    errors = [str(f) for f in found if f.severity == "error"]
    assert len(errors) == 1 and errors[0].startswith("t.yaml:10:")
    assert f"type '{KEY}' has no parameter 'noise_rd'; did you mean 'noise_rad'?" in errors[0]
    notes = [f for f in found if f.code == "plugin-api"]
    assert len(notes) == 1 and notes[0].severity == "warning"
    assert notes[0].path == "modules.compass.type" and notes[0].line == 10


def test_a_type_that_declares_parameters_is_left_alone() -> None:
    assert registry.migrate("sensor.imu", Imu) is None and "sensor.imu" not in registry.LEGACY
