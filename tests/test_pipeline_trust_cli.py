"""``selfcal to-raw`` and ``selfcal render`` warn, naming the file, when a share of its pixels
lies outside the colours the model was trained on; the mask is the model's own
(:meth:`selfcal.pipeline.PipelineModel.outside_training`)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from selfcal.io import read_image, write_image
from selfcal.pipeline import PipelineOptions, fit_pipeline
from selfcal.io.raw import read_raw_linear
from selfcal_cli.main import main
from selfcal_cli.pipeline_commands import WARN_OUTSIDE
from conftest import dim_training_pixels

WARNING = re.compile(r"warning: (.+): ([0-9.]+) % of its pixels have (raw|rendered) colours "
                     r"outside those the model was trained on")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A model fitted to the dim, weakly coloured half of a simulated pair, saved; the
    training pixels themselves, and bright saturated colours it never saw."""
    folder = tmp_path_factory.mktemp("trust")
    raw, jpg, pick = dim_training_pixels()
    model = fit_pipeline(raw[pick], jpg[pick] / 255.0,
                         PipelineOptions(n_sets=2, backward="lut", bake_size=17), seed=0)
    path = model.save(folder / "camera.json")
    far_raw = np.random.default_rng(1).uniform([0.7, 0.0, 0.0], [0.95, 0.05, 0.05],
                                               (400, 3))
    far_jpg = np.random.default_rng(2).integers([230, 0, 0], [256, 20, 20], (400, 3),
                                                dtype=np.uint8)
    return {"folder": folder, "model": model, "path": path, "raw": raw[pick],
            "jpg": jpg[pick], "far_raw": far_raw, "far_jpg": far_jpg}


def _run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def _raw_tiff(path, raw):
    write_image(path, (np.clip(raw, 0, 1) * 65535).round().astype(np.uint16))
    return path


def test_render_warns_with_the_share_of_raw_pixels_outside(trained, tmp_path, capsys):
    inside = _raw_tiff(tmp_path / "inside.tiff", trained["raw"].reshape(30, 40, 3))
    # a quarter of the frame bright red, which the training pixels never showed
    mixed = np.concatenate([trained["raw"][:1200], trained["far_raw"]]).reshape(40, 40, 3)
    outside = _raw_tiff(tmp_path / "outside.tiff", mixed)
    code, text = _run(["render", "--model", trained["path"], inside, outside,
                       "-o", tmp_path / "jpg"], capsys)
    assert code == 0, text
    assert (tmp_path / "jpg" / "inside.jpg").is_file()
    assert (tmp_path / "jpg" / "outside.jpg").is_file()
    found = WARNING.findall(text)
    assert len(found) == 1, text              # the inside frame: no warning
    name, share, kind = found[0]
    assert name == str(outside) and kind == "raw"
    # the printed share is the mask's, on the frame as the command reads it
    mask = trained["model"].outside_training(read_raw_linear(outside).rgb, "raw")
    assert float(share) == pytest.approx(100 * mask.mean(), abs=0.05)
    assert 20 <= float(share) <= 30           # the red quarter, give or take its edge
    assert text.count(str(outside)) == 1      # one sentence
    inside_mask = trained["model"].outside_training(read_raw_linear(inside).rgb, "raw")
    assert inside_mask.mean() < WARN_OUTSIDE


def test_to_raw_warns_with_the_share_of_rendered_pixels_outside(trained, tmp_path, capsys):
    inside = write_image(tmp_path / "inside.png", trained["jpg"].reshape(30, 40, 3))
    mixed = np.concatenate([trained["jpg"][:800], trained["far_jpg"]]).reshape(30, 40, 3)
    outside = write_image(tmp_path / "outside.png", mixed)
    code, text = _run(["to-raw", "--model", trained["path"], inside, outside,
                       "-o", tmp_path / "raw"], capsys)
    assert code == 0, text
    assert (tmp_path / "raw" / "outside.tiff").is_file()
    found = WARNING.findall(text)
    assert len(found) == 1, text
    name, share, kind = found[0]
    assert name == str(outside) and kind == "rendered"
    mask = trained["model"].outside_training(read_image(outside), "rendered")
    assert float(share) == pytest.approx(100 * mask.mean(), abs=0.05)
    assert 30 <= float(share) <= 37           # 400 of 1,200 pixels far red
    assert not trained["model"].outside_training(read_image(inside), "rendered").any()


def test_a_model_without_training_colours_gives_no_warning(trained, tmp_path, capsys):
    import json

    doc = json.loads(trained["path"].read_text())
    assert "training_colours" in json.dumps(doc)
    old = tmp_path / "old.json"
    old.write_text(json.dumps(_without(doc, "training_colours")))
    outside = write_image(tmp_path / "far.png", trained["far_jpg"].reshape(20, 20, 3))
    code, text = _run(["to-raw", "--model", old, outside, "-o", tmp_path / "raw"], capsys)
    assert code == 0, text
    assert not WARNING.findall(text)


def _without(doc, key):
    """``doc`` with ``key`` removed wherever it is (a model saved before the training colours were kept)."""
    if isinstance(doc, dict):
        return {k: _without(v, key) for k, v in doc.items() if k != key}
    if isinstance(doc, list):
        return [_without(v, key) for v in doc]
    return doc
