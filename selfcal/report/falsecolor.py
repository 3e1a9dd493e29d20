"""A false-colour picture of a radiance map's luminance, on a log scale with a legend.

In the manner of Radiance's ``falsecolor -log`` (G. Ward): each pixel's luminance
``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (Rec. 709, :data:`selfcal.lens.luminance.REC709_LUMA`)
is drawn in a colour of a perceptually ordered map (matplotlib's ``turbo``) on a
logarithmic scale, with the scale as a legend in cd/m² (or in relative units when the map
is relative).  Pixels no frame measured (:attr:`selfcal.hdr.HDRResult.unmeasured`) are
grey.  matplotlib, Agg backend; the PNG is written atomically.
"""

from __future__ import annotations

import io as _io
import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import write_bytes_atomic
from ..lens.luminance import luminance_of
from ..typing import PathLike

__all__ = ["falsecolor_range", "write_falsecolor"]

#: The largest side of the picture in pixels (larger maps are subsampled).
MAX_SIDE = 1600


def falsecolor_range(luminance: np.ndarray,
                     mask: np.ndarray | None = None) -> tuple[float, float]:
    """The legend's range: the 0.5th and 99.9th percentiles of the positive luminance
    (over ``mask``), widened to whole 1-2-5 steps; (1e-3, 1) when nothing is positive."""
    y = np.asarray(luminance, np.float64)
    if mask is not None:
        y = y[np.asarray(mask, bool)]
    y = y[np.isfinite(y) & (y > 0)]
    if y.size == 0:
        return 1e-3, 1.0
    lo, hi = np.percentile(y, [0.5, 99.9])
    steps = (1.0, 2.0, 5.0, 10.0)
    e = math.floor(math.log10(lo))
    lo = max(s * 10 ** e for s in steps if s * 10 ** e <= lo)
    e = math.floor(math.log10(hi))
    hi = min(s * 10 ** e for s in steps if s * 10 ** e >= hi)
    return float(lo), float(max(hi, lo * 10))


def write_falsecolor(path: PathLike, radiance: np.ndarray, *, units: str = "relative",
                     mask: np.ndarray | None = None,
                     value_range: tuple[float, float] | None = None, force: bool = False,
                     inputs: Iterable[PathLike] = ()) -> Path:
    """Write a PNG of the luminance of ``radiance`` in false colour with a log legend.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.png``.
    radiance : numpy.ndarray
        ``HxWx3`` linear RGB (:attr:`selfcal.hdr.HDRResult.radiance`).
    units : {"relative", "cd/m2"}
        Of the radiance (:attr:`selfcal.hdr.HDRResult.units`): the legend's label.
    mask : numpy.ndarray, optional
        bool ``HxW``: pixels not measured (drawn grey, left out of the range).
    value_range : (float, float), optional
        The legend's ends; default :func:`falsecolor_range`.
    force, inputs
        As in :func:`selfcal.hdr.io.write_radiance`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"the false-colour picture is a .png, not {path.suffix!r}", path)
    arr = np.asarray(radiance)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"expected an HxWx3 radiance array, got shape {arr.shape}", path)
    step = max(1, math.ceil(max(arr.shape[:2]) / MAX_SIDE))
    y = luminance_of(arr[::step, ::step])
    bad = (np.zeros(y.shape, bool) if mask is None
           else np.asarray(mask, bool)[::step, ::step])
    lo, hi = falsecolor_range(y, ~bad) if value_range is None else value_range
    if not (0 < lo < hi):
        raise InputError(f"a false-colour range needs 0 < low < high, not {lo}, {hi}", path)
    shown = np.ma.masked_array(np.clip(y, lo, hi), mask=bad | ~(y > 0))
    cmap = matplotlib.colormaps["turbo"].copy()
    cmap.set_bad("0.5")
    h, w = y.shape
    fig, ax = plt.subplots(figsize=(min(10.0, 2.0 + 7.0 * w / max(h, w)) + 1.4,
                                    0.8 + 7.0 * h / max(h, w)))
    image = ax.imshow(shown, cmap=cmap, norm=LogNorm(lo, hi), interpolation="nearest")
    ax.set_axis_off()
    label = "luminance (cd/m²)" if units == "cd/m2" else "relative luminance (1 = white at e = 1)"
    bar = fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03)
    bar.set_label(label)
    ax.set_title(f"{label}, log scale" + ("; grey: unmeasured" if bad.any() else ""),
                 fontsize=9)
    fig.tight_layout()
    buf = _io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_bytes_atomic(path, buf.getvalue(), force=force, inputs=inputs)
