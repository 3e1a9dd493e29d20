"""ResponseModel: the result of the JPEG-only calibration, and its model file.

A model holds each channel's inverse response f⁻¹ as a dense table on normalised
intensity (f⁻¹(1) = 1), the log-PCA coefficients it came from (Lin et al., ICCV 2011,
Eq. 7), the estimated exposures, and diagnostics.  Files are versioned JSON (see
:mod:`selfcal.io.model_file`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pathlib import Path

import numpy as np
import numpy.typing as npt

from ..errors import InputError, ModelFileError
from ..typing import PathLike
from ..io.model_file import IGNORED_FRAME_REASONS, jsonable, save_model_dict
from ..lens.luminance import LuminanceScale
from ..lens.vignetting import Vignetting
from ..exposure.record import BracketExposures

MODEL_KIND = "response"


@dataclass(frozen=True)
class IgnoredFrame:
    """A frame the calibration left out of its solve, and why.

    Attributes
    ----------
    source : str
        The frame, as named in :attr:`ResponseModel.sources`.
    reason : {"clipped", "duplicate", "unchecked"}
        ``"clipped"``: clipped almost everywhere (white or black); ``"duplicate"``: the
        same pixels as an earlier frame; ``"unchecked"``: it shares too few unclipped
        samples with any other frame (too far from the rest of the bracket), so the pixels
        could check neither its exposure nor the curve with it -- the merge still merges
        such a frame with its time, flagged (:func:`selfcal.merge_hdr`).  One of
        :data:`selfcal.io.model_file.IGNORED_FRAME_REASONS`.
    detail : str
        For people: what was measured (the model's warning says the same).
    """

    source: str
    reason: str
    detail: str = ""

    def __post_init__(self) -> None:
        if self.reason not in IGNORED_FRAME_REASONS:
            raise InputError(f"IgnoredFrame.reason must be one of "
                             f"{', '.join(IGNORED_FRAME_REASONS)}, not {self.reason!r}")

    def to_dict(self) -> dict:
        return {"source": self.source, "reason": self.reason, "detail": self.detail}


#: The words by which model files of versions 1 and 2 told an unchecked frame, in its
#: warning (:func:`_ignored_from_warnings`, the compatibility path of older files).
_UNCHECKED_WORDS = "too far from the rest of the bracket"


def _ignored_from_warnings(d: dict) -> tuple[IgnoredFrame, ...]:
    """The ignored frames of a model file of version 1 or 2, which said them in prose only.

    As the merge of those versions read them: a source missing from
    ``diagnostics["frames_used"]`` (none when that is absent) with a warning
    ``"<source>: <detail>; ignored"``; the detail names the reason ("duplicate of ...",
    "... too far from the rest of the bracket ...", else clipped).  Used by the loader
    only: models of version 3 carry :attr:`ResponseModel.frames_ignored` as data.
    """
    diag = d.get("diagnostics") or {}
    used = diag.get("frames_used")
    if used is None:
        return ()
    used = {str(f) for f in used}
    out = []
    for name in d.get("sources", []):
        if name in used:
            continue
        text = next((w[len(name) + 2:] for w in diag.get("warnings", [])
                     if w.startswith(f"{name}: ") and "ignored" in w), None)
        if text is None:
            continue
        detail = text.replace("; ignored", "").strip()
        reason = ("unchecked" if _UNCHECKED_WORDS in detail else
                  "duplicate" if detail.startswith("duplicate of") else "clipped")
        out.append(IgnoredFrame(source=name, reason=reason, detail=detail))
    return tuple(out)


@dataclass
class ResponseModel:
    """Per-channel camera response recovered from an exposure stack.

    Attributes
    ----------
    intensity : ndarray, shape (K,)
        Normalised intensity grid on [0, 1] (code / max code).
    inverse : ndarray, shape (K, 3)
        f⁻¹ per channel (R, G, B) on ``intensity``; increasing; f⁻¹(1) = 1.
    coefficients : ndarray, shape (3, N)
        Log-PCA coefficients cₙ of Eq. 7 per channel.
    basis_name : str
    exposures : ndarray, shape (F,)
        Estimated exposure of each frame, in the units of the given times (seconds), or
        relative to a reference frame when no two times were known.
    exposure_times : list of float or None
        The times given (EXIF or the caller), None where unknown.
    sources : list of str
        The frames, in the order of ``exposures``.
    max_code : int
        255 for 8-bit stacks, 65535 for 16-bit.
    diagnostics : dict
        Fit residuals, δ of Eq. 12, per-pair residuals, samples used and rejected by
        reason, ``warnings`` and the verdict
        (:mod:`selfcal.response.verdict`): ``verdict`` (``"ok"``, ``"doubtful"`` or
        ``"unusable"``), ``verdict_reasons`` (one sentence each, also among the
        warnings) and ``verdict_evidence`` (the numbers they rest on).  Saved with the
        model and read back as they were.
    inverse_log_sigma : ndarray, shape (K, 3), or None
        Standard deviation of log f⁻¹ on ``intensity`` per channel, the confidence band
        of the fit (:mod:`selfcal.response.bands`, ours); None for models loaded from
        files of version 1, which have no band.
    frames_ignored : tuple of IgnoredFrame
        The frames the calibration left out of its solve, each with its reason (a code)
        and a detail for people; their exposures are NaN.  What the merge reads to know
        which frames to leave out or to merge unchecked.  Saved with the model (file
        format version 3); for files of versions 1 and 2 derived once, on loading, from
        their warnings (:func:`_ignored_from_warnings`).
    vignetting : Vignetting or None
        The lens's falloff (:class:`selfcal.lens.Vignetting`, ``.map(height, width)``), when
        the calibration observed it (frames that moved, ``align="homography"``,
        :mod:`selfcal.response.vignetting_fit`) or it was attached from a lens profile or a
        flat field; None otherwise.  Saved with the model (file format version 4).
    luminance : LuminanceScale or None
        The camera's absolute scale, cd/m² per unit of the radiance this model's merges
        give (:mod:`selfcal.lens.luminance`), when one was measured (``selfcal merge
        --reference ... --save-scale``); later merges apply it with
        ``MergeOptions(luminance="model")``.  Saved with the model (format version 4).
    exposure_record : BracketExposures or None
        Every frame's exposures (:class:`selfcal.exposure.BracketExposures`): the given
        time and where it came from, the solve's, the measured and the used one (which
        :attr:`exposures` holds), the times the pixels contradict, the rule that chose,
        and the measurement's spread.  Saved with the model (file format version 5); for
        older files derived on loading from their diagnostics.
    """

    intensity: np.ndarray
    inverse: np.ndarray
    coefficients: np.ndarray
    basis_name: str
    exposures: np.ndarray
    exposure_times: list
    sources: list
    max_code: int = 255
    diagnostics: dict = field(default_factory=dict)
    inverse_log_sigma: np.ndarray | None = None
    frames_ignored: tuple[IgnoredFrame, ...] = ()
    vignetting: Vignetting | None = None
    luminance: LuminanceScale | None = None
    exposure_record: BracketExposures | None = None
    #: samples of one frame pair with rejection reasons (for plots); not saved
    fit_data: dict | None = field(default=None, repr=False, compare=False)

    # ------------------------------------------------------------------ curves
    def inverse_response(self, codes: npt.ArrayLike | None = None) -> np.ndarray:
        """f⁻¹ per channel at integer ``codes`` (default every code 0…max_code), (n, 3)."""
        if codes is None:
            codes = np.arange(self.max_code + 1)
        x = np.asarray(codes, dtype=float) / self.max_code
        return np.stack([np.interp(x, self.intensity, self.inverse[:, c]) for c in range(3)],
                        axis=-1)

    def response(self, irradiance: npt.ArrayLike) -> np.ndarray:
        """The forward response f per channel: normalised irradiance in [0, 1] → [0, 1].

        ``irradiance`` of shape (n,) is evaluated for each channel, giving (n, 3).
        """
        e = np.clip(np.asarray(irradiance, dtype=float), 0.0, 1.0)
        return np.stack([np.interp(e, self.inverse[:, c], self.intensity) for c in range(3)],
                        axis=-1)

    def inverse_band(self, level: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """The two-sided confidence band of f⁻¹ at ``level``: ``(lower, upper)``.

        Each is shaped like :attr:`inverse` (same grid, same normalisation: both are 1 at
        intensity 1), ``inverse · exp(∓z σ)`` with σ = :attr:`inverse_log_sigma` and z the
        normal quantile of (1 + level)/2 (:func:`selfcal.response.bands.band_from_sigma`).

        Raises
        ------
        InputError
            When the model has no band (loaded from a version 1 model file: calibrate
            again to get one).
        ValueError
            ``level`` not in (0, 1).
        """
        if self.inverse_log_sigma is None:
            raise InputError("this response model has no confidence band (its model file "
                             "predates version 2); calibrate again to get one")
        from .bands import band_from_sigma

        return band_from_sigma(self.inverse, self.inverse_log_sigma, level)

    def band_at_codes(self, codes: npt.ArrayLike | None = None,
                      level: float = 0.9) -> tuple[np.ndarray, ...]:
        """:meth:`inverse_band` at integer ``codes`` (default every code), each (n, 3)."""
        lower, upper = self.inverse_band(level)
        if codes is None:
            codes = np.arange(self.max_code + 1)
        x = np.asarray(codes, dtype=float) / self.max_code
        return tuple(np.stack([np.interp(x, self.intensity, t[:, c]) for c in range(3)],
                              axis=-1) for t in (lower, upper))

    def lookup_table(self) -> np.ndarray:
        """f⁻¹ at every code of the model's bit depth, float32, shape (max_code+1, 3)."""
        return self.inverse_response().astype(np.float32)

    def linearize(self, image: npt.ArrayLike) -> np.ndarray:
        """Apply the inverse response per channel: codes → linear values, f⁻¹(max) = 1.

        Parameters
        ----------
        image : ndarray
            ``HxWx3`` uint8 or uint16 RGB (as the stack was), or float in [0, 1].

        Returns
        -------
        ndarray, float32, same shape
        """
        arr = np.asarray(image)
        if arr.ndim < 1 or arr.shape[-1] != 3:
            raise InputError(f"expected RGB values with 3 channels last, got shape {arr.shape}")
        if arr.dtype in (np.uint8, np.uint16):
            max_code = 255 if arr.dtype == np.uint8 else 65535
            if max_code == self.max_code:
                lut = self.lookup_table()
            else:
                lut = self.inverse_response(
                    np.arange(max_code + 1) * (self.max_code / max_code)).astype(np.float32)
            out = np.empty(arr.shape, dtype=np.float32)
            for c in range(3):
                out[..., c] = lut[arr[..., c], c]
            return out
        if np.issubdtype(arr.dtype, np.floating):
            if not np.all(np.isfinite(arr)):
                raise InputError("image holds NaN or infinite values")
            x = np.clip(arr, 0.0, 1.0)
            out = np.empty(arr.shape, dtype=np.float32)
            for c in range(3):
                out[..., c] = np.interp(x[..., c], self.intensity, self.inverse[:, c])
            return out
        raise InputError(f"unsupported image dtype {arr.dtype}")

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {
            "kind": MODEL_KIND,
            "basis": self.basis_name,
            "max_code": int(self.max_code),
            "intensity": self.intensity.tolist(),
            "inverse_response": self.inverse.T.tolist(),
            "coefficients": self.coefficients.tolist(),
            "exposures": jsonable(np.asarray(self.exposures, dtype=float)),  # NaN: ignored
            "exposure_times": [None if t is None else float(t) for t in self.exposure_times],
            "sources": list(self.sources),
            "diagnostics": jsonable(self.diagnostics),
            "frames_ignored": [f.to_dict() for f in self.frames_ignored],
            **({} if self.vignetting is None else
               {"vignetting": jsonable(self.vignetting.to_dict())}),
            **({} if self.luminance is None else {"luminance": self.luminance.to_dict()}),
            **({} if self.exposure_record is None else
               {"exposure_record": jsonable(self.exposure_record.as_dict())}),
            **({} if self.inverse_log_sigma is None else
               {"inverse_log_sigma": np.round(np.asarray(self.inverse_log_sigma).T,
                                              7).tolist()}),
        }

    @classmethod
    def from_dict(cls, d: dict, *, path: PathLike | None = None) -> "ResponseModel":
        from ..io.model_file import check_response_content

        check_response_content(d, path)   # every field, before any is used

        def bad(msg):
            return ModelFileError(msg, path)

        try:
            intensity = np.asarray(d["intensity"], dtype=float)
            inverse = np.asarray(d["inverse_response"], dtype=float).T
            coefficients = np.asarray(d["coefficients"], dtype=float)
            exposures = np.asarray(d["exposures"], dtype=float)
            max_code = int(d["max_code"])
            model = cls(intensity=intensity, inverse=inverse, coefficients=coefficients,
                        basis_name=str(d["basis"]), exposures=exposures,
                        exposure_times=list(d["exposure_times"]), sources=list(d["sources"]),
                        max_code=max_code, diagnostics=dict(d.get("diagnostics", {})),
                        inverse_log_sigma=(None if d.get("inverse_log_sigma") is None else
                                           np.asarray(d["inverse_log_sigma"], float).T),
                        frames_ignored=(
                            _ignored_from_warnings(d) if d.get("frames_ignored") is None
                            else tuple(IgnoredFrame(source=f["source"], reason=f["reason"],
                                                    detail=f.get("detail", ""))
                                       for f in d["frames_ignored"])),
                        vignetting=(None if d.get("vignetting") is None
                                    else Vignetting.from_dict(d["vignetting"])),
                        luminance=(None if d.get("luminance") is None
                                   else LuminanceScale.from_dict(d["luminance"])),
                        exposure_record=_exposure_record(d))
        except KeyError as exc:
            raise bad(f"response model lacks the field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise bad(f"response model has a malformed field ({exc})") from None
        if intensity.ndim != 1 or inverse.shape != (intensity.size, 3) or intensity.size < 2:
            raise bad("inverse_response must be 3 lists as long as intensity")
        if not (np.all(np.isfinite(inverse)) and np.all(np.isfinite(intensity))):
            raise bad("the response tables hold NaN or infinite values")
        if np.any(np.diff(intensity) <= 0) or np.any(np.diff(inverse, axis=0) < 0):
            raise bad("the response tables are not increasing")
        if max_code not in (255, 65535):
            raise bad(f"max_code must be 255 or 65535, not {max_code}")
        return model

    def save(self, path: PathLike, *, force: bool = False) -> Path:
        """Write the model as versioned JSON, atomically (refuses to overwrite unless force).

        Returns the path written.
        """
        return save_model_dict(path, self.to_dict(), force=force)


def _exposure_record(d: dict) -> BracketExposures:
    """A model file's exposure record (version 5), or one derived from the diagnostics of
    an older file (:func:`selfcal.exposure.resolve.record_from_diagnostics`)."""
    if d.get("exposure_record") is not None:
        return BracketExposures.from_dict(d["exposure_record"])
    from ..exposure.resolve import record_from_diagnostics

    return record_from_diagnostics(list(d["sources"]), np.asarray(d["exposures"], float),
                                   list(d["exposure_times"]), dict(d.get("diagnostics") or {}))
