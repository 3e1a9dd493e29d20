"""What a model is, in words and numbers: the content of ``selfcal show`` (ours).

:func:`describe` gathers, from a loaded model of either kind (:func:`selfcal.load_model`),
what it is (kind, camera when recorded, frames, exposures and where they came from, the
solver's settings), its fit (residuals; δ of Lin et al., ICCV 2011, Eq. 12, where
present), its verdict (:mod:`selfcal.response.verdict`: ok / doubtful / unusable with
reasons), its warnings, a compact table of its curves and, when the model carries one, its
vignetting ([Goldman2010] Eq. 4: source, centre, corner falloff with its band), as plain
values (JSON-able).
:func:`format_description` turns that into text.  The library never prints: the command
line (``selfcal_cli/show_commands.py``) does.

For a :class:`~selfcal.response.ResponseModel` the curves are f⁻¹ per channel at a few
codes; for a :class:`~selfcal.pipeline.PipelineModel` the colour matrix M (Gong et al.,
rank-based calibration, §3.2), the forward tone curves f (Eq. 9) and their inverses at a
few inputs, the backward variant (lattice LUT or RBF h⁻¹, Lin et al. Eq. 10) with its
validation error, and the training colours kept for the trust test
(:mod:`selfcal.pipeline.trust`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["describe", "format_description", "describe_vignetting", "TABLE_FRACTIONS",
           "VIGNETTING_FRACTIONS"]

#: Where the curve tables are read: fractions of the largest code (response models: the
#: codes round(fraction · max_code); pipeline models: fractions of each curve's domain).
TABLE_FRACTIONS = (0.0, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
from ..io.images import format_exposure_time  # noqa: E402
from ..lens.vignetting import Vignetting  # noqa: E402
from ..response.verdict import verdict_of  # noqa: E402


def _verdict(diagnostics: dict):
    return verdict_of(diagnostics)


def _floats(x):
    return [float(v) for v in np.asarray(x, dtype=float).reshape(-1)]


def describe(model) -> dict:
    """Everything ``selfcal show`` says about a model, as plain values.

    Parameters
    ----------
    model : ResponseModel or PipelineModel

    Returns
    -------
    dict
        ``kind``, ``what`` (a list of (label, value) pairs), ``fit`` (the same),
        ``verdict`` (level or None), ``verdict_reasons``, ``warnings``, ``curves``
        (``{"title", "header", "rows"}`` tables) and, for a response model, ``vignetting``
        (:func:`describe_vignetting`, None when the model has none).
    """
    if hasattr(model, "to_raw"):
        return _describe_pipeline(model)
    return _describe_response(model)


def _describe_response(model) -> dict:
    d = dict(model.diagnostics or {})
    level, reasons = _verdict(d)
    times = list(model.exposure_times)
    exposures = _floats(model.exposures)
    frames = [{"source": str(s), "given": None if t is None else float(t),
               "estimated": e} for s, t, e in zip(model.sources, times, exposures)]
    used = d.get("frames_used")
    what = [
        ("kind", "response (JPEG-only path: per-channel f⁻¹, Lin et al. ICCV 2011 §5)"),
        ("camera", d.get("camera") or "not recorded in the model"),
        ("basis", f"{model.basis_name}, N = {d.get('n_components', model.coefficients.shape[1])}"
                  " components (Eq. 7)"),
        ("codes", f"0..{model.max_code} ({'8' if model.max_code == 255 else '16'}-bit)"),
        ("frames", f"{len(frames)}" + (f" ({len(used)} used)" if used is not None
                                      and len(used) != len(frames) else "")),
        ("exposure times from", _exposure_origin(model)),
        ("settings", ", ".join(f"{k} {d[k]}" for k in (
            "saturation_threshold", "clip_margin",
            "monotone_constrained", "ambiguity_resolved_by_prior") if k in d)
         or "not recorded"),
    ]
    samples = d.get("samples") or {}
    rejected = samples.get("rejected") or {}
    fit = []
    if "residual_rms_log" in d:
        fit.append(("residual RMS (log units)", f"{float(d['residual_rms_log']):.4g}"))
    if d.get("delta_eq12") is not None:
        fit.append(("δ (Eq. 12) R G B", " ".join(f"{v:.4g}" for v in _floats(d["delta_eq12"]))))
    if "exposure_ratio" in d:
        fit.append(("exposure ratio covered", f"{float(d['exposure_ratio']):.4g}"))
    if samples:
        fit.append(("samples", f"{samples.get('valid_locations', '?')} valid locations of "
                    f"{samples.get('locations', '?')}; pair rows used "
                    f"{samples.get('pair_rows_used', '?')}; rejected "
                    + (", ".join(f"{k} {v}" for k, v in rejected.items()) or "none")))
    ev = d.get("verdict_evidence") or {}
    if "residual_noise_ratio" in ev:
        fit.append(("residuals / noise", f"{float(ev['residual_noise_ratio']):.3g}"))
    if "stops_covered" in ev:
        fit.append(("stops covered R G B", " ".join(f"{v:.3g}"
                                                    for v in _floats(ev["stops_covered"]))))
    fit.append(("90 % band of f⁻¹", _band_line(model)))
    codes = sorted({int(round(f * model.max_code)) for f in TABLE_FRACTIONS})
    inv = model.inverse_response(codes)
    curves = [{"title": "f⁻¹ (relative irradiance, f⁻¹(max) = 1)",
               "header": ["code", "R", "G", "B"],
               "rows": [[c, *(_floats(inv[i]))] for i, c in enumerate(codes)]}]
    return {"kind": "response", "what": what, "frames": frames, "fit": fit,
            "verdict": level, "verdict_reasons": reasons,
            "warnings": [str(w) for w in d.get("warnings") or [] if str(w) not in reasons],
            "curves": curves, "vignetting": describe_vignetting(
                getattr(model, "vignetting", None))}


#: Where the vignetting table is read: fractions of the way from the optical centre to
#: the farthest corner.
VIGNETTING_FRACTIONS = (0.0, 0.25, 0.5, 0.75, 1.0)


def describe_vignetting(vignetting: Vignetting | None) -> dict | None:
    """What ``selfcal show`` says about a model's vignetting (None when it has none).

    Returns
    -------
    dict or None
        ``source``, ``description``, ``centre`` (offset from the image centre, half
        diagonals), ``aspect``, ``corner_stops`` (falloff at the farthest corner,
        −log₂ V per channel, :meth:`~selfcal.lens.vignetting.Vignetting.corner_stops`),
        ``corner_band_stops`` (half-width of its 90 % band: 1.645 σ of log V from the
        covariance and the floor, in stops) and ``table`` (V per channel and the band, at
        :data:`VIGNETTING_FRACTIONS` of the way to that corner).
    """
    if vignetting is None:
        return None
    profile = vignetting.corner_profile(len(VIGNETTING_FRACTIONS))
    band = 1.645 * profile["log_sigma"] / math.log(2.0)
    rows = [[float(profile["r"][i]), *_floats(profile["falloff"][i]),
             float(band[i].max())] for i in range(len(VIGNETTING_FRACTIONS))]
    return {"source": vignetting.source, "description": vignetting.description,
            "centre": _floats(vignetting.centre),
            "aspect": None if vignetting.aspect is None else float(vignetting.aspect),
            "corner_stops": _floats(vignetting.corner_stops()),
            "corner_band_stops": _floats(band[-1]),
            "covariance": vignetting.covariance is not None,
            "log_sigma_floor": float(vignetting.log_sigma_floor),
            "table": {"title": "vignetting V (r: half diagonals from the optical centre "
                               "towards the farthest corner; ± stops: 90 % band, widest "
                               "channel)",
                      "header": ["r", "R", "G", "B", "± stops"], "rows": rows}}


_SOURCES = {"self": "self-calibrated from the frames", "lens": "lens database profile",
            "flat": "flat field"}


def _vignetting_lines(v: dict) -> list[str]:
    stops = " ".join(f"{s:.3f}±{b:.3f}" for s, b in zip(v["corner_stops"],
                                                         v["corner_band_stops"]))
    band_from = ("covariance" + (" and floor" if v["log_sigma_floor"] else "")
                 if v["covariance"] else
                 (f"floor {v['log_sigma_floor']:g} (log V at r = 1)"
                  if v["log_sigma_floor"] else "none stated"))
    aspect = "any (a lens profile)" if v["aspect"] is None else f"{v['aspect']:.4g} (w/h)"
    lines = ["", "vignetting:",
             f"  source       {v['source']} ({_SOURCES.get(v['source'], v['source'])})",
             f"  description  {v['description'] or 'none'}",
             f"  centre       {v['centre'][0]:+.4f} {v['centre'][1]:+.4f} (x y, half "
             "diagonals from the image centre)",
             f"  frames       aspect {aspect}",
             f"  corner R G B {stops} stops (falloff at the farthest corner, 90 % band)",
             f"  band from    {band_from}"]
    return lines


def _band_line(model) -> str:
    """The widest 90 % band over the body of the curve, and where (or why none)."""
    if getattr(model, "inverse_log_sigma", None) is None:
        return "none (model file version 1: calibrate again for a band)"
    from ..response.bands import BODY, widest_band

    wide = widest_band(model.intensity, model.inverse, model.inverse_log_sigma)
    lo, hi = (round(b * model.max_code) for b in BODY)
    code = int(round(wide["intensity"] * model.max_code))
    return (f"widest ±{100 * wide['width']:.1f} % at code {code} of {'RGB'[wide['channel']]}"
            f" (over codes {lo}..{hi})")


def _describe_pipeline(model) -> dict:
    d = dict(model.diagnostics or {})
    level, reasons = _verdict(d)
    samples = d.get("samples") or {}
    what = [
        ("kind", "pipeline (RAW path: colour matrix, tone curves, gamut LUT, inverse "
                 "mapping; Gong et al. §3.2-3.5, Lin et al. ICCV 2011 §6)"),
        ("camera", d.get("camera") or "not recorded in the model"),
        ("method", d.get("method", "not recorded")),
        ("samples", ", ".join(f"{k} {v}" for k, v in samples.items()) or "not recorded"),
        ("backward", f"{model.backward}" + (f" (selection {d['backward_selection']})"
                                             if "backward_selection" in d else "")
         + f"; baked table {model.bake_size}³"),
        ("settings", ", ".join(f"{k} {d[k]}" for k in (
            "seed", "forward_lut_smoothness", "inverse_tone_smoothness",
            "backward_lut_smoothness", "rbf_smoothing", "neutral_weighting") if k in d)
         or "not recorded"),
    ]
    fit = []
    if "forward_train_rmse" in d:
        fit.append(("forward training RMSE (codes /255)",
                    f"{float(d['forward_train_rmse']):.4g}"
                    + (f" ({float(d['forward_train_rmse_without_lut']):.4g} without the LUT)"
                       if "forward_train_rmse_without_lut" in d else "")))
    for key, label in (("backward_validation_rmse", "backward validation RMSE (raw)"),
                       ("backward_train_rmse", "backward training RMSE (raw)")):
        if isinstance(d.get(key), dict):
            fit.append((label, ", ".join(f"{k} {float(v):.4g}" for k, v in d[key].items()
                                         if v is not None)))
    if "validation" in d:
        fit.append(("validation", str(d["validation"])))
    tc = model.training_colours
    if tc is None:
        trust = "no training colours kept (a model saved before they were)"
    else:
        trust = (f"{tc.raw.shape[0]} training colours kept; outside beyond {tc.radius:g} "
                 f"(encoded units; raw scale {tc.raw_scale:.4g})")
    what.append(("trust", trust))
    kept = [v for v, c in model.clipped_corrections.items() if c is not None]
    what.append(("clipped-pixel correction", ", ".join(kept) if kept else "none"))
    matrix = {"title": "colour matrix M (raw -> tone-curve input)",
              "header": ["", "R", "G", "B"],
              "rows": [["RGB"[i], *_floats(model.matrix[i])] for i in range(3)]}
    curves = [matrix]
    for poly, title in ((model.tone_curves, "tone curves f (M ρ -> rendered)"),
                        (model.inverse_tone_curves, "inverse tone curves f⁻¹ (rendered -> M ρ)")):
        rows = []
        for frac in TABLE_FRACTIONS:
            x = poly.domain[:, 0] + frac * (poly.domain[:, 1] - poly.domain[:, 0])
            y = [float(poly.channel(np.array(x[k]), k)) for k in range(3)]
            rows.append([frac, *_floats(x), *y])
        curves.append({"title": title + f", degree {poly.degree}",
                       "header": ["at", "x R", "x G", "x B", "R", "G", "B"], "rows": rows})
    return {"kind": "pipeline", "what": what, "frames": [], "fit": fit,
            "verdict": level, "verdict_reasons": reasons,
            "warnings": [str(w) for w in d.get("warnings") or [] if str(w) not in reasons],
            "curves": curves}


def _fmt_time(t) -> str:
    if t is None or not math.isfinite(t):
        return "?"
    return f"{format_exposure_time(t)} s ({t:.6g})"


def _cell(v) -> str:
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{float(v):.4f}"


def format_description(desc: dict, *, name: str | None = None) -> str:
    """The text of :func:`describe`'s result (what ``selfcal show`` prints).

    Numbers in the curve tables have four decimals; exposures are written as a
    photographer would (1/250 s) followed by the value in seconds to six digits.
    """
    out = []
    if name:
        out.append(f"model: {name}")
    width = max(len(k) for k, _ in desc["what"] + desc["fit"]) if desc["fit"] else \
        max(len(k) for k, _ in desc["what"])
    for k, v in desc["what"]:
        out.append(f"{k:<{width}}  {v}")
    if desc["frames"]:
        out.append("")
        out.append("frames (given time -> estimated exposure):")
        for i, f in enumerate(desc["frames"]):
            out.append(f"  {i + 1:>2}. {Path(f['source']).name}: given {_fmt_time(f['given'])}"
                       f" -> estimated {_fmt_time(f['estimated'])}")
    out.append("")
    out.append("fit:")
    for k, v in desc["fit"] or [("", "not recorded")]:
        out.append(f"  {k:<{width}}  {v}")
    out.append("")
    if desc["verdict"] is None:
        out.append("verdict: none recorded" + (" (RAW-path models carry no verdict)"
                                               if desc["kind"] == "pipeline" else ""))
    else:
        out.append(f"verdict: {desc['verdict']}")
    for r in desc["verdict_reasons"]:
        out.append(f"  - {r}")
    out.append("warnings: " + ("none" if not desc["warnings"] else ""))
    for w in desc["warnings"]:
        out.append(f"  - {w}")
    vignetting = desc.get("vignetting")
    if vignetting is not None:
        out.extend(_vignetting_lines(vignetting))
    tables = desc["curves"] + ([vignetting["table"]] if vignetting is not None else [])
    for table in tables:
        out.append("")
        out.append(table["title"] + ":")
        cells = [[_cell(v) for v in row] for row in table["rows"]]
        widths = [max(len(h), *(len(r[j]) for r in cells)) for j, h in
                  enumerate(table["header"])]
        out.append("  " + "  ".join(h.rjust(w) for h, w in zip(table["header"], widths)))
        for r in cells:
            out.append("  " + "  ".join(c.rjust(w) for c, w in zip(r, widths)))
    return "\n".join(out) + "\n"


def _exposure_origin(model) -> str:
    """Where the model's exposures came from, and the rule that chose them, in words (from
    its :attr:`~selfcal.ResponseModel.exposure_record`)."""
    record = getattr(model, "exposure_record", None)
    if record is None:
        return "not recorded"
    kind = {"measured": "measured from the pixels", "solved": "solved (Eq. 8)",
            "given": "as given"}[record.used_from]
    return f"{record.origin}; used {kind} (rule: times {record.rule})"
