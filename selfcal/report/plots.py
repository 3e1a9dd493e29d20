"""Plots of a calibration (matplotlib, Agg backend; files only, nothing shown).

The response figure follows Lin et al., ICCV 2011, Fig. 3: the recovered inverse response
curves, and a brightness transfer function scatter of one frame pair with the rejected
samples marked by reason (clipped; highly saturated, HSV S > β); a model with a vignetting
adds its falloff V(r) ([Goldman2010] Eq. 4) with its band and the measured points.  The calibration's verdict
(:mod:`selfcal.response.verdict`) heads the figure, with its reasons.
"""

from __future__ import annotations

import io as _io

from pathlib import Path
from typing import Any, cast

import numpy as np

from ..io.images import write_bytes_atomic
from ..lens.vignetting import Vignetting
from ..pipeline.model import PipelineModel
from ..response.model import ResponseModel
from ..typing import PathLike

CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")
VERDICT_COLOURS = {"ok": "tab:green", "doubtful": "tab:orange", "unusable": "tab:red"}


def verdict_lines(diagnostics: dict, width: int = 110, max_reasons: int = 4) -> list[str]:
    """The verdict and its reasons as short lines for a figure (wrapped at ``width``)."""
    import textwrap

    verdict = str(diagnostics.get("verdict", "not recorded"))
    reasons = list(diagnostics.get("verdict_reasons", []))
    lines = [f"verdict: {verdict}" + (f" ({len(reasons)} reason"
                                      f"{'s' if len(reasons) != 1 else ''})"
                                      if reasons else "")]
    for reason in reasons[:max_reasons]:
        lines += textwrap.wrap(f"- {reason}", width, subsequent_indent="  ")
    if len(reasons) > max_reasons:
        lines.append(f"- and {len(reasons) - max_reasons} more (see the model's diagnostics)")
    return lines


def plot_response(model: ResponseModel, path: PathLike, *, truth: np.ndarray | None = None,
                  force: bool = False) -> Path:
    """Write a PNG with the inverse curves and a BTF scatter with rejections by reason.

    Parameters
    ----------
    model : ResponseModel
        A model from :func:`selfcal.calibrate_response` (its ``fit_data`` gives the
        scatter; a model loaded from file shows the curves only).
    path : path
        Output PNG, written atomically.
    truth : ndarray, optional
        True f⁻¹ at codes 0…max_code, shape (max_code+1, 3), drawn dashed.

    The verdict (``model.diagnostics["verdict"]``) and its reasons head the figure, in
    green, orange or red for ok, doubtful and unusable.  A model with a confidence band
    (:meth:`selfcal.response.model.ResponseModel.inverse_band`) has its 90 % band shaded.
    A model with a vignetting (``model.vignetting``) gets a third panel
    (:func:`draw_vignetting`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fit = getattr(model, "fit_data", None)
    vignetting = getattr(model, "vignetting", None)
    ncols = 1 + (fit is not None) + (vignetting is not None)
    diagnostics = getattr(model, "diagnostics", {}) or {}
    header = verdict_lines(diagnostics, width=55 * ncols)
    top = 0.25 + 0.16 * len(header)          # inches above the axes for the verdict
    fig, axes = plt.subplots(1, ncols, figsize=(5.2 * ncols, 4.4 + top), squeeze=False)
    ax = axes[0, 0]
    band = (model.inverse_band(0.9) if getattr(model, "inverse_log_sigma", None) is not None
            else None)
    for c, colour in enumerate(CHANNEL_COLOURS):
        ax.plot(model.intensity, model.inverse[:, c], color=colour, lw=1.6,
                label=f"{'RGB'[c]} f⁻¹")
        if band is not None:
            ax.fill_between(model.intensity, band[0][:, c], band[1][:, c], color=colour,
                            alpha=0.18, lw=0, label="90 % band" if c == 0 else None)
        if truth is not None:
            codes = np.arange(truth.shape[0]) / (truth.shape[0] - 1)
            ax.plot(codes, truth[:, c], color=colour, lw=1, ls="--", alpha=0.8)
    if truth is not None:
        ax.plot([], [], "k--", lw=1, label="truth")
    ax.set_xlabel("normalised intensity I")
    ax.set_ylabel("f⁻¹(I) (relative irradiance)")
    ax.set_title("Inverse response per channel")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    if fit is not None:
        ax = axes[0, 1]
        labels = {0: ("used", "k", 4, 0.35), 1: ("clipped", "tab:orange", 10, 0.8),
                  2: ("saturated (S > β)", "tab:purple", 10, 0.8)}
        for code, (label, colour, size, alpha) in labels.items():
            sel = fit["reason"] == code
            if sel.any():
                ax.scatter(fit["I"][sel].ravel(), fit["I2"][sel].ravel(), s=size, c=colour,
                           alpha=alpha, marker="x" if code else ".", lw=0.6,
                           label=f"{label} ({int(sel.sum())})")
        x = np.linspace(0, 1, 256)
        lin = model.inverse_response(np.round(x * model.max_code))
        for c, colour in enumerate(CHANNEL_COLOURS):
            pred = np.interp(np.clip(lin[:, c] * fit["ratio"], 0, 1), model.inverse[:, c],
                             model.intensity)
            ax.plot(x, pred, color=colour, lw=1)
        ax.set_xlabel(f"I  ({_short(fit['frames'][0])})")
        ax.set_ylabel(f"I′ ({_short(fit['frames'][1])})")
        ax.set_title(f"Brightness transfer, ratio {fit['ratio']:.2f}")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
    if vignetting is not None:
        draw_vignetting(axes[0, ncols - 1], vignetting)
    fig.tight_layout(rect=(0, 0, 1, 1 - top / (4.4 + top)))
    colour = VERDICT_COLOURS.get(diagnostics.get("verdict", ""), "black")
    fig.text(0.01, 0.995, header[0], ha="left", va="top", fontsize=10, weight="bold",
             color=colour)
    if len(header) > 1:
        fig.text(0.01, 0.995 - 0.17 / (4.4 + top), "\n".join(header[1:]), ha="left",
                 va="top", fontsize=8, color=colour, linespacing=1.25)
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue(), force=force)


def draw_vignetting(ax: Any, vignetting: Vignetting) -> None:
    """Draw a vignetting's falloff ``V(r)`` per channel ([Goldman2010] Eq. 4) on ``ax``.

    The fitted curve from the optical centre to the farthest corner
    (:meth:`~selfcal.lens.vignetting.Vignetting.corner_profile`), its 90 % band shaded
    (1.645 σ of log V: covariance and floor), and the measurements the fit saw when
    ``vignetting.diagnostics["points"]`` holds them (binned ``log V`` against r, see
    :class:`~selfcal.lens.vignetting.Vignetting`) as dots.
    """
    profile = vignetting.corner_profile(65)
    r = profile["r"]
    points = (vignetting.diagnostics or {}).get("points")
    for c, colour in enumerate(CHANNEL_COLOURS):
        v, s = profile["falloff"][:, c], 1.645 * profile["log_sigma"][:, c]
        ax.plot(r, v, color=colour, lw=1.6, label=f"{'RGB'[c]} V(r)")
        if np.any(s > 0):
            ax.fill_between(r, v * np.exp(-s), v * np.exp(s), color=colour, alpha=0.18,
                            lw=0, label="90 % band" if c == 0 else None)
        if points:
            pr = np.asarray(points["r"], float)
            lr = np.array([np.nan if row[c] is None else row[c]
                           for row in points["log_ratio"]], float)
            ax.plot(pr, np.exp(lr), ".", color=colour, ms=4, alpha=0.8,
                    label="measured (binned)" if c == 0 else None)
    stops = vignetting.corner_stops()
    ax.set_title(f"Vignetting ({vignetting.source}): corner "
                 + " ".join(f"{v:.2f}" for v in stops) + " stops", fontsize=10)
    ax.set_xlabel("r (half diagonals from the optical centre)")
    ax.set_ylabel("V (relative illumination)")
    ax.set_xlim(0, float(r[-1]) * 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    if vignetting.description:
        import textwrap

        ax.text(0.98, 0.98, "\n".join(textwrap.wrap(vignetting.description, 40)),
                transform=ax.transAxes, ha="right", va="top", fontsize=7)


def plot_vignetting(vignetting: Vignetting, path: PathLike, *, force: bool = False) -> Path:
    """Write a PNG of a vignetting alone (:func:`draw_vignetting`), atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    draw_vignetting(ax, vignetting)
    fig.tight_layout()
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue(), force=force)


def _short(name: str) -> str:
    import os

    return os.path.basename(name)


def plot_pipeline(model: PipelineModel, path: PathLike, *, force: bool = False) -> Path:
    """Write a PNG of a RAW-path model's tone curves, forward and inverse, per channel.

    Left: the forward tone curves ``f`` (Gong et al., rank-based calibration, Eq. 9) from
    ``M ρ`` to rendered values; right: their inverses ``f⁻¹`` (§3.5).  The colour matrix
    ``M`` and the backward variant are written above the axes (ours: a summary figure for
    ``selfcal show``).

    Parameters
    ----------
    model : PipelineModel
    path : path
        Output PNG, written atomically (refused over an existing file unless ``force``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.4, 5.0))
    for ax, poly, title, xl, yl in (
            (axes[0], model.tone_curves, "Tone curves f (Eq. 9)", "M ρ", "rendered"),
            (axes[1], model.inverse_tone_curves, "Inverse tone curves f⁻¹ (§3.5)",
             "rendered", "M ρ")):
        for c, colour in enumerate(CHANNEL_COLOURS):
            x, y = poly.table(c, 512)
            ax.plot(x, y, color=colour, lw=1.6, label=f"{'RGB'[c]}")
        ax.set_title(title)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    m = model.matrix
    rows = "   ".join("[" + " ".join(f"{v:+.3f}" for v in m[i]) + "]" for i in range(3))
    fig.text(0.01, 0.99, f"M = {rows}    backward: {model.backward}", ha="left", va="top",
             fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue(), force=force)


def plot_model(model: ResponseModel | PipelineModel, path: PathLike, *,
               force: bool = False) -> Path:
    """The curves of a model of either kind: :func:`plot_response` (a response model, its
    verdict above) or :func:`plot_pipeline` (a RAW-path model)."""
    if hasattr(model, "to_raw"):
        return plot_pipeline(cast(PipelineModel, model), path, force=force)
    return plot_response(model, path, force=force)
