"""The diagnostics a calibration writes into its model: how the fit went (the verdict,
the residuals, the samples, δ of [Lin2011] Eq. 12), for the report and the CLI.

References
----------
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
"""

from __future__ import annotations

__all__ = ["fit_diagnostics"]


def fit_diagnostics(result, fit: dict, *, warnings, options, frames_used, samples) -> dict:
    """The model's ``diagnostics``: how the fit went, for the report and the CLI.

    ``fit`` is :func:`selfcal.response.calibrate._judged_fit`'s; ``options`` the
    :class:`selfcal.response.options.ResponseOptions` of the calibration.  ``delta_eq12`` is δ of Eq. 12
    (:func:`selfcal.response.delta.delta_eq12`) per channel over the solve's frame pairs
    and inliers (samples neither clipped nor above β in either frame: what the curve was
    fitted to), not over all points as [Lin2011] scores its Fig. 4.  The exposures are
    not here: they are the model's :attr:`~selfcal.ResponseModel.exposure_record`.
    """
    verdict, reasons, evidence = fit["verdict"], fit["reasons"], fit["evidence"]
    per_pair = {f"{frames_used[a]} -> {frames_used[b]}": v
                for (a, b), v in result.per_pair_rms.items()}
    return {
        "verdict": verdict,
        "verdict_reasons": list(reasons),
        "verdict_evidence": evidence,
        "warnings": warnings,
        "ambiguity_resolved_by_prior": bool(result.ambiguity_prior),
        "n_components": options.solver.n_components,
        "saturation_threshold": options.solver.saturation_threshold,
        "clip_margin": options.solver.clip_margin,
        "frames_used": frames_used,
        "residual_rms_log": result.residual_rms,
        "per_pair_rms_log": per_pair,
        "delta_eq12": fit["delta"].tolist(),
        "samples": {
            "locations": int(samples.n_samples),
            "block_size": int(samples.block),
            "pair_rows_used": int(result.rows_used),
            "pair_rows_downweighted": int(result.rows_downweighted),
            "rejected": dict(result.rejections),
            "valid_locations": evidence["valid_locations"],
            "code_coverage": evidence["code_coverage"],
        },
        "monotone_constrained": bool(result.monotone_constrained),
        "exposure_ratio": evidence["exposure_ratio"],
    }
