"""What a person reads about a model.

* :mod:`selfcal.report.plots` -- the response, band and transfer plots (re-exported here);
* :mod:`selfcal.report.describe` -- the text of ``selfcal show``;
* :mod:`selfcal.report.falsecolor` -- a radiance map's luminance in false colour, a log
  legend in cd/m² (``selfcal merge --falsecolor``)."""

from __future__ import annotations

from .falsecolor import write_falsecolor
from .plots import (CHANNEL_COLOURS, VERDICT_COLOURS, draw_vignetting, plot_model,
                    plot_pipeline, plot_response, plot_vignetting, verdict_lines)

__all__ = ["CHANNEL_COLOURS", "VERDICT_COLOURS", "verdict_lines", "plot_response",
           "plot_pipeline", "plot_model", "plot_vignetting", "draw_vignetting",
           "write_falsecolor"]
