"""The frames a calibration ignored are data on the model, not prose in its warnings.

``ResponseModel.frames_ignored`` (reason codes ``"clipped"``, ``"duplicate"``,
``"unchecked"``) is what the merge reads; it is saved with the model (file format version
3) and, for files of versions 1 and 2, derived once from their warnings on loading.  The
acceptance test of issue 34: rewording every warning of the calibration, in memory and
in the saved file, leaves the merged radiance unchanged bit for bit.
"""

from __future__ import annotations

import copy
import json
import warnings

import numpy as np
import pytest

import selfcal
from selfcal.errors import InputError, ModelFileError, SelfcalWarning
from selfcal.hdr import MergeOptions, merge_hdr
from selfcal.io import write_image
from selfcal.response.model import IgnoredFrame
from test_hdr import far_bracket


@pytest.fixture(scope="module")
def far_stack(tmp_path_factory):
    """Four bracketed frames and one far beyond them (as in test_hdr): the right half of
    the scene is black in the bracket and measured by the long frame alone; plus a
    duplicate of frame 1.  The calibration ignores the duplicate and the far frame.
    Written as PNG files: the merge finds a given model's frames by their paths."""
    st, far = far_bracket()
    arrays = list(st.images) + list(far.images) + [st.images[1].copy()]
    folder = tmp_path_factory.mktemp("far")
    images = [write_image(folder / f"f{k}.png", a) for k, a in enumerate(arrays)]
    times = list(st.exposure_times) + [512.0, st.exposure_times[1]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SelfcalWarning)
        model = selfcal.calibrate_response(images, times)
    return images, times, model


def _reworded(messages):
    """Every message replaced by other words (no reason, no frame name, no 'ignored')."""
    return [f"note {k}: something else entirely" for k, _ in enumerate(messages)]


def test_the_calibration_records_what_it_ignored_and_why(far_stack):
    images, _, model = far_stack
    assert [(f.source, f.reason) for f in model.frames_ignored] == [   # in frame order
        (str(images[4]), "unchecked"), (str(images[5]), "duplicate")]
    assert model.frames_ignored[1].detail == f"duplicate of {images[1]}"
    assert "too far from the rest of the bracket" in model.frames_ignored[0].detail
    # the warnings say the same, for people
    for f in model.frames_ignored:
        assert f"{f.source}: {f.detail}; ignored" in model.diagnostics["warnings"]
    assert np.isnan(model.exposures[[4, 5]]).all()


def test_reworded_warnings_give_the_same_radiance_bit_for_bit(far_stack, tmp_path):
    images, times, model = far_stack
    before = merge_hdr(images, times, model)
    assert before.diagnostics["frames_unchecked"] == [str(images[4])]
    assert before.diagnostics["frames_ignored"] == [str(images[5])]

    reworded = copy.deepcopy(model)
    reworded.diagnostics["warnings"] = _reworded(model.diagnostics["warnings"])
    reworded.diagnostics["verdict_reasons"] = _reworded(model.diagnostics["verdict_reasons"])
    after = merge_hdr(images, times, reworded)
    np.testing.assert_array_equal(after.radiance, before.radiance)
    np.testing.assert_array_equal(after.unchecked, before.unchecked)
    assert after.diagnostics["frames_unchecked"] == [str(images[4])]

    # the same through a saved file whose warnings were reworded
    path = model.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["version"] == 5
    assert [f["reason"] for f in doc["frames_ignored"]] == ["unchecked", "duplicate"]
    doc["diagnostics"]["warnings"] = _reworded(doc["diagnostics"]["warnings"])
    doc["diagnostics"]["verdict_reasons"] = _reworded(doc["diagnostics"]["verdict_reasons"])
    (tmp_path / "reworded.json").write_text(json.dumps(doc))
    loaded = selfcal.load_model(tmp_path / "reworded.json")
    assert loaded.frames_ignored == model.frames_ignored
    from_file = merge_hdr(images, times, loaded)
    np.testing.assert_array_equal(from_file.radiance, before.radiance)
    np.testing.assert_array_equal(from_file.unchecked, before.unchecked)


def test_version_2_files_derive_the_ignored_frames_from_their_warnings(far_stack, tmp_path):
    images, times, model = far_stack
    doc = json.loads(model.save(tmp_path / "m.json").read_text())
    doc["version"] = 2
    del doc["frames_ignored"]
    (tmp_path / "v2.json").write_text(json.dumps(doc))
    old = selfcal.load_model(tmp_path / "v2.json")
    assert old.frames_ignored == model.frames_ignored
    np.testing.assert_array_equal(merge_hdr(images, times, old).radiance,
                                  merge_hdr(images, times, model).radiance)
    # without frames_used (older still), nothing was ignored, as the merge of then read it
    del doc["diagnostics"]["frames_used"]
    (tmp_path / "v1.json").write_text(json.dumps({**doc, "version": 1}))
    assert selfcal.load_model(tmp_path / "v1.json").frames_ignored == ()


def test_merge_unchecked_false_leaves_the_far_frame_out(far_stack):
    images, times, model = far_stack
    result = merge_hdr(images, times, model, options=MergeOptions(merge_unchecked=False))
    assert result.unchecked is None
    assert result.diagnostics["frames_ignored"] == [str(images[4]), str(images[5])]


def test_bad_ignored_frames_are_refused(far_stack, tmp_path):
    _, _, model = far_stack
    with pytest.raises(InputError, match="reason"):
        IgnoredFrame(source="a.jpg", reason="blurry")
    doc = json.loads(model.save(tmp_path / "m.json").read_text())
    bad = copy.deepcopy(doc)
    bad["frames_ignored"][1]["reason"] = "blurry"
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ModelFileError, match="frames_ignored.*reason"):
        selfcal.load_model(tmp_path / "bad.json")
    bad = copy.deepcopy(doc)
    bad["frames_ignored"][0]["source"] = "elsewhere.jpg"
    (tmp_path / "bad2.json").write_text(json.dumps(bad))
    with pytest.raises(ModelFileError, match="not among the sources"):
        selfcal.load_model(tmp_path / "bad2.json")
