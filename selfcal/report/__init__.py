"""What a person reads about a model: plots (:mod:`selfcal.report.plots`, re-exported here)
and the text of ``selfcal show`` (:mod:`selfcal.report.describe`)."""

from __future__ import annotations

from .plots import (CHANNEL_COLOURS, VERDICT_COLOURS, plot_model, plot_pipeline,
                    plot_response, verdict_lines)

__all__ = ["CHANNEL_COLOURS", "VERDICT_COLOURS", "verdict_lines", "plot_response",
           "plot_pipeline", "plot_model"]
