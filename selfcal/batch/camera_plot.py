"""Per camera body, a picture: each session's curve over the pooled one, with verdicts.

Beside ``cameras.csv`` the batch writes ``camera-<camera>.png`` per camera body: the
inverse response of every session's own calibration (:func:`own_curve`, the mean of its
R, G and B curves, kept in the session's manifest row) drawn in the colour of its verdict
(ok, doubtful, unusable: :mod:`selfcal.response.verdict`), dashed when the pooled fit
flagged it (it disagrees with its camera's shared curve and was fitted alone), under the
camera's shared curve (:mod:`.pooled`, the Eq. 7-8 solver of [Lin2011] on samples pooled
across sessions) in black.  The counts head the figure.  Where the camera has a RAW-path
model from its RAW+JPEG pairs (:mod:`.raw_camera`), a second panel draws each scene's
forward error (0-255) under the model fitted without it (leave-one-scene-out) beside
its error under the model fitted on it, with the means; the header gives the backward
errors.  Ours; matplotlib, Agg backend, files only.
"""

from __future__ import annotations

import io as _io
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:
    from ..response.model import ResponseModel

#: Points of a session's curve kept in its manifest row (codes 0, 1/32, ..., 1).
CURVE_POINTS = 33
VERDICT_COLOURS = {"ok": "tab:green", "doubtful": "tab:orange", "unusable": "tab:red"}


def _grey_curve(intensity, inverse, n: int = CURVE_POINTS) -> list:
    inverse = np.asarray(inverse, dtype=float)
    grey = inverse.mean(axis=1) if inverse.ndim == 2 else inverse
    x = np.linspace(0.0, 1.0, n)
    return [round(float(v), 5) for v in np.interp(x, np.asarray(intensity, float), grey)]


def own_curve(model) -> list:
    """A session's own f⁻¹ at :data:`CURVE_POINTS` codes, mean of its channels."""
    return _grey_curve(model.intensity, model.inverse)


def plot_name(camera: str) -> str:
    """The file name of a camera's plot (beside ``cameras.csv``)."""
    return f"camera-{camera}.png"


def _shared_curve(model_file: str):
    if not model_file:
        return None
    try:
        from ..choose.loading import load_model

        m = cast("ResponseModel", load_model(model_file))     # a camera's shared curve
        return _grey_curve(m.intensity, m.inverse)
    except Exception:  # noqa: BLE001 -- a plot never fails the batch
        return None


def _header(cam: dict, rows: list) -> list:
    verdicts = Counter(str(r.get("verdict")) for r in rows if r.get("verdict"))
    flagged = cam.get("flagged_sessions") or []
    lines = [f"{cam['camera_label']}: {cam['sessions']} sessions, "
             f"{len(cam.get('pooled_sessions') or [])} in the pooled fit, "
             f"{len(flagged)} flagged (fitted alone), {cam.get('failed', 0)} failed",
             "verdicts of the sessions' own fits: " + (", ".join(
                 f"{v} {verdicts[v]}" for v in ("ok", "doubtful", "unusable")
                 if verdicts[v]) or "none")]
    if not cam.get("model_file"):
        lines.append("no shared curve" + (f": {cam['fit_error']}" if cam.get("fit_error")
                                          else ""))
    if flagged:
        more = f" and {len(flagged) - 4} more" if len(flagged) > 4 else ""
        lines.append("flagged: " + ", ".join(flagged[:4]) + more)
    if cam.get("raw_model_file"):
        lines.append(f"RAW-path model from {len(cam.get('raw_scenes') or [])} scenes' "
                     f"RAW+JPEG pairs (λ {cam.get('raw_smoothness'):g}): forward "
                     f"{cam['raw_loso_forward']:.2f} codes on unseen scenes, "
                     f"{cam['raw_training_forward']:.2f} on its own; backward "
                     f"{cam['raw_loso_backward']:.4f} / {cam['raw_training_backward']:.4f}")
    elif cam.get("raw_fit_error"):
        lines.append(f"no RAW-path model: {cam['raw_fit_error']}")
    return lines


def _raw_panel(ax, cam: dict) -> None:
    """Per scene: forward error unseen (leave-one-scene-out) and on its own scene."""
    scenes = cam.get("raw_scene_errors") or []
    k = np.arange(len(scenes))
    loso = [s["loso_forward"] for s in scenes]
    train = [s["training_forward"] for s in scenes]
    ax.bar(k - 0.2, loso, 0.4, color="tab:purple", label="scene left out")
    ax.bar(k + 0.2, train, 0.4, color="tab:gray", label="scene in the fit")
    ax.axhline(float(np.mean(loso)), color="tab:purple", ls="--", lw=1)
    ax.axhline(float(np.mean(train)), color="tab:gray", ls="--", lw=1)
    ax.set_xticks(k, [str(i + 1) for i in k], fontsize=7)
    ax.set_xlabel("scene (camera row: raw_scenes)")
    ax.set_ylabel("RAW-path forward RMSE, 0-255")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(loc="upper left", fontsize=8)


def render_camera_plot(cam: dict, rows: list) -> bytes:
    """The PNG of one camera (its :func:`.run.camera_rows` row and its sessions' rows)."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    x = np.linspace(0.0, 1.0, CURVE_POINTS)
    header = [w for line in _header(cam, rows) for w in textwrap.wrap(line, 95)]
    top = 0.25 + 0.15 * len(header)              # inches above the axes for the text
    raw = bool(cam.get("raw_scene_errors"))
    fig, axes = plt.subplots(1, 2 if raw else 1, figsize=(11.5 if raw else 6.4, 4.4 + top),
                             squeeze=False)
    ax = axes[0, 0]
    if raw:
        _raw_panel(axes[0, 1], cam)
    for flagged in (False, True):
        for verdict, colour in VERDICT_COLOURS.items():
            curves = [np.column_stack([x, r["own_curve"]]) for r in rows
                      if r.get("own_curve") and bool(r.get("flagged")) == flagged
                      and r.get("verdict") == verdict]
            if curves:
                ax.add_collection(LineCollection(
                    curves, colors=colour, linewidths=1.6 if flagged else 0.8,
                    linestyles="--" if flagged else "-", alpha=0.9 if flagged else 0.5))
                ax.plot([], [], color=colour, ls="--" if flagged else "-",
                        label=f"{'flagged, ' if flagged else ''}{verdict} ({len(curves)})")
    shared = _shared_curve(cam.get("model_file", ""))
    if shared is not None:
        ax.plot(x, shared, color="black", lw=2.4, label="camera curve (pooled)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("normalised intensity I")
    ax.set_ylabel("f⁻¹(I), mean of R, G, B")
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", fontsize=8)
    fig.text(0.02, 1 - 0.1 / (4.4 + top), "\n".join(header), fontsize=8, ha="left",
             va="top")
    fig.subplots_adjust(left=0.11 * (0.56 if raw else 1), right=0.97, wspace=0.25, bottom=0.6 / (4.4 + top),
                        top=1 - (top + 0.1) / (4.4 + top))
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def camera_plot_writers(out_dir, cameras: list, rows: list) -> dict:
    """``{path: writer(tmp)}`` of every camera's plot; sets each camera row's ``plot``."""
    by_camera: dict = {}
    for r in rows:
        by_camera.setdefault(r["camera"], []).append(r)
    writers = {}
    for cam in cameras:
        path = Path(out_dir) / plot_name(cam["camera"])
        cam["plot"] = str(path)
        members = by_camera.get(cam["camera"], [])
        writers[path] = (lambda tmp, cam=cam, members=members:
                         Path(tmp).write_bytes(render_camera_plot(cam, members)))
    return writers
