"""1.0's names of the rule for given times still work until 2.0, each with a
DeprecationWarning naming the replacement (CHANGELOG, "Deprecation policy";
``selfcal.exposure.legacy`` holds the mapping)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.exposure import ExposureRule
from selfcal.hdr import MergeOptions

HELD = ExposureRule(times="held")


@pytest.mark.parametrize("legacy, rule", [
    ({"measure_exposures": False}, HELD),
    ({"refine_exposures": False}, HELD),
    ({"refine_exposures": True}, ExposureRule(refine=True)),
    ({"refine_exposures": "auto"}, ExposureRule()),
    ({"linear_exposures": "times"}, HELD),
    ({"linear_exposures": "measured"}, ExposureRule()),
    ({"exposure_trend": "pixels"}, ExposureRule(trend="pixels")),
    ({"measure_exposures": False, "exposure_trend": "pixels"},
     ExposureRule(times="held", trend="pixels")),
])
def test_merge_options_of_1_0_map_to_the_rule(legacy, rule):
    with pytest.warns(DeprecationWarning, match="removed in 2.0: write exposures="):
        options = MergeOptions(sigma=True, **legacy)
    assert options == MergeOptions(sigma=True, exposures=rule)


def test_bad_1_0_values_are_refused_as_1_0_refused_them():
    with pytest.raises(selfcal.InputError, match="linear_exposures must be one of"):
        MergeOptions(linear_exposures="exif")
    with pytest.raises(selfcal.InputError, match="refine_exposures must be"):
        selfcal.calibrate_response([np.zeros((4, 4, 3), np.uint8)] * 2, [1, 2],
                                   refine_exposures="yes")


def test_calibrate_response_refine_exposures_false_holds_the_times():
    stack = sim.demo_stack(seed=1)
    times = list(stack.exposure_times)
    times[2] *= 1.6
    with pytest.warns(DeprecationWarning, match="calibrate_response"):
        old = selfcal.calibrate_response(stack.images, times, refine_exposures=False)
    new = selfcal.calibrate_response(stack.images, times, exposures=HELD)
    assert old.exposure_record.rule == "held"
    np.testing.assert_array_equal(old.exposures, new.exposures)
    np.testing.assert_array_equal(old.inverse, new.inverse)


def test_cli_flags_of_1_0_mean_hold_times(tmp_path, capsys):
    from selfcal_cli.main import main

    stack = sim.demo_stack(seed=2)
    paths = stack.write(tmp_path / "s")
    assert main(["calibrate", *map(str, paths), "-o", str(tmp_path / "m.json"),
                 "--no-refine-exposures"]) == 0
    err = capsys.readouterr().err
    assert "--no-refine-exposures is the 1.0 flag" in err and "--hold-times" in err
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["exposure_record"]["rule"] == "held"
