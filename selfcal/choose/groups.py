"""The inputs of a calibration by role: rendered frames, RAW+rendered pairs, unpaired raws
(:func:`group_inputs`), and whether a bracket of 16-bit TIFFs is linear data rather than
rendered frames (:func:`linear_evidence`).

Part of the path choice of :mod:`selfcal.choose`, which re-exports :class:`InputGroups`
and :func:`group_inputs`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import IMAGE_SUFFIXES, read_image
from ..pipeline.pairs import split_thumbnails
from ..io.raw import RAW_SUFFIXES, TIFF_SUFFIXES, is_linear_tiff, is_raw_path

__all__ = ["InputGroups", "group_inputs", "linear_evidence", "RENDERED_SUFFIXES"]

RENDERED_SUFFIXES = frozenset(IMAGE_SUFFIXES)
#: Preference among rendered files of one name when pairing with a raw.
_RENDERED_PREFERENCE = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
#: TIFF PhotometricInterpretation of linear raw data (DNG's LinearRaw).
PHOTOMETRIC_LINEAR_RAW = 34892
#: A bracket is linear when the pixel ratio between two frames is the same at every
#: brightness: the medians of log(ratio) over the four quartiles of the darker frame's
#: values differ by at most this share of the median log ratio (a rendered curve's toe and
#: shoulder change the ratio with brightness: 15-20 % on the simulator's default camera) ...
LINEAR_RATIO_SPREAD = 0.05
#: ... and, where exposure times are known, the ratios follow them to the power
#: 1 ± LINEAR_EXPONENT_TOLERANCE (a rendered curve's log-log slope is 0.4-0.7).
LINEAR_EXPONENT_TOLERANCE = 0.15
#: Frame pairs whose exposures (or median values) differ by less than this factor say
#: little about linearity.
LINEAR_MIN_EXPOSURE_RATIO = 1.5


# ---- grouping ------------------------------------------------------------------------

@dataclass
class InputGroups:
    """The inputs sorted by role.

    Attributes
    ----------
    rendered : list of pathlib.Path
        Every rendered frame (JPEG, PNG, TIFF that is not taken as a raw), in input order,
        including those paired with a raw.
    pairs : list of (pathlib.Path, pathlib.Path)
        ``(raw, rendered)`` pairs: same folder, same name up to case and suffix.
    unpaired_raws : list of pathlib.Path
        Raw files without a rendered file of the same name.
    ignored : list of (pathlib.Path, str)
        Files not used, with the reason (duplicates, a second raw of one name).
    folders : dict
        Each folder given → the image and raw files found in it (maybe none); files named
        one by one are in no folder's list.
    """

    rendered: list = field(default_factory=list)
    pairs: list = field(default_factory=list)
    unpaired_raws: list = field(default_factory=list)
    ignored: list = field(default_factory=list)
    folders: dict = field(default_factory=dict)

    @property
    def from_folder(self) -> set:
        """The files found by expanding a folder (not named one by one)."""
        return {p for files in self.folders.values() for p in files}

    @property
    def raw_of(self) -> dict:
        """Map rendered path → its raw path."""
        return {j: r for r, j in self.pairs}


def _expand(paths, folders: dict) -> list[Path]:
    """The files named, folders expanded (their files also recorded in ``folders``)."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    out: list[Path] = []
    for p in paths:
        if not isinstance(p, (str, os.PathLike)):
            raise InputError(f"calibrate takes file paths; got {type(p).__name__} "
                             "(use calibrate_response / calibrate_pipeline for arrays)")
        p = Path(p)
        if p.is_dir():
            try:
                found = sorted(q for q in p.iterdir() if q.is_file() and (
                    is_raw_path(q) or q.suffix.lower() in RENDERED_SUFFIXES))
            except OSError as exc:
                raise InputError(f"the folder cannot be read ({exc.strerror})", p) from None
            folders[p] = found
            out.extend(found)
        elif not p.exists():
            raise InputError("no such file", p)
        else:
            out.append(p)
    return out


def group_inputs(paths) -> InputGroups:
    """Sort input files into rendered frames, RAW+rendered pairs and unpaired raws.

    A raw file (suffix in :data:`selfcal.io.raw.RAW_SUFFIXES`) pairs with the rendered file
    (``.jpg``/``.jpeg``/``.png``/``.tif``/``.tiff``) of the same name -- case-insensitive,
    same folder; JPEG is preferred when several exist.  A 16-bit (or float) TIFF is taken as
    the raw of a pair when a rendered file of the same name is given and no camera raw is
    (``pair.tiff`` + ``pair.jpg``); otherwise a TIFF is a rendered frame.  Directories are
    expanded to their image and raw files (not recursively).  A file given twice is used
    once.

    Parameters
    ----------
    paths : str, os.PathLike or sequence of them

    Returns
    -------
    InputGroups

    Raises
    ------
    InputError
        For a missing file or a file that is neither an image nor a raw file.
    """
    groups = InputGroups()
    files = _expand(paths, groups.folders)
    seen: dict[Path, Path] = {}
    unique: list[Path] = []
    for p in files:
        key = p.resolve()
        if key in seen:
            groups.ignored.append((p, f"given twice (same file as {seen[key]})"))
            continue
        seen[key] = p
        suffix = p.suffix.lower()
        if not is_raw_path(p) and suffix not in RENDERED_SUFFIXES:
            raise InputError(
                "not an image or raw file selfcal reads (JPEG, PNG, TIFF, or a camera raw: "
                + ", ".join(sorted(s.lstrip(".").upper() for s in RAW_SUFFIXES)) + ")", p)
        unique.append(p)

    by_stem: dict[tuple, list[Path]] = {}
    for p in unique:
        # the folder as given (a symlink is not followed: its name is what pairs)
        by_stem.setdefault((Path(os.path.abspath(p)).parent, p.stem.lower()), []).append(p)

    raw_of: dict[Path, Path] = {}
    is_raw: set[Path] = set()
    for members in by_stem.values():
        raws = [p for p in members if is_raw_path(p)]
        others = [p for p in members if not is_raw_path(p)]
        if not raws and len(others) >= 2:
            tiffs = [p for p in others if p.suffix.lower() in TIFF_SUFFIXES
                     and is_linear_tiff(p)]
            if tiffs and len(tiffs) < len(others):
                raws = tiffs[:1]
                others = [p for p in others if p != raws[0]]
        for extra in raws[1:]:
            groups.ignored.append((extra, f"a second raw file named like {raws[0].name}; "
                                          f"only {raws[0].name} is used"))
        if raws:
            is_raw.update(raws)
            if others:
                partner = min(others, key=lambda q: (
                    _RENDERED_PREFERENCE.index(q.suffix.lower()), unique.index(q)))
                raw_of[partner] = raws[0]
            else:
                groups.unpaired_raws.append(raws[0])
    for p in unique:
        if p in is_raw:
            continue
        groups.rendered.append(p)
        if p in raw_of:
            groups.pairs.append((raw_of[p], p))
    ignored_raws = {p for p, _ in groups.ignored}
    groups.unpaired_raws = [p for p in unique if p in groups.unpaired_raws
                            and p not in ignored_raws]
    return groups


# ---- linear data ---------------------------------------------------------------------

def _grey_thumbnails(path, side: int = 256):
    """The frame's mean of the channels on [0, 1] as two half-frame thumbnails of about
    ``side`` pixels a side, (values, selection) of :func:`selfcal.pipeline.pairs.split_thumbnails`
    (NaN where a clipped value went in)."""
    img = read_image(path)
    white = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
    values, selection = split_thumbnails(img.astype(np.float32) / np.float32(white),
                                         max_side=side)
    return values.mean(axis=2), selection.mean(axis=2)


def _photometric_linear_raw(path) -> bool:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            return int(tif.pages[0].photometric) == PHOTOMETRIC_LINEAR_RAW
    except Exception:  # an unreadable TIFF is not said to be linear
        return False


def _ratio_profile(a, b):
    """log(b / a) over pixels well exposed in both, and the spread of its values over the
    quartiles of ``a`` relative to it; None with too few pixels.

    ``a`` and ``b`` are (values, selection) half-frame thumbnails: pixels are chosen and
    put in quartiles by the selection half and measured (log of the ratio of sums) on the
    other, so that the noise does not bend the profile at its ends.
    """
    (av, asel), (bv, bsel) = a, b
    ok = ((asel > 0.01) & (bsel > 0.01) & (asel < 0.9) & (bsel < 0.9)
          & np.isfinite(av) & np.isfinite(bv) & (av > 0) & (bv > 0))
    if ok.sum() < 64:
        return None
    av, bv, asel = av[ok], bv[ok], asel[ok]
    edges = np.quantile(asel, [0.0, 0.25, 0.5, 0.75, 1.0])
    levels = [float(np.log(bv[m].sum() / av[m].sum()))
              for lo, hi in zip(edges[:-1], edges[1:])
              if (m := (asel >= lo) & (asel <= hi)).any()]
    level = float(np.log(bv.sum() / av.sum()))
    if abs(level) < math.log(LINEAR_MIN_EXPOSURE_RATIO):
        return None
    return level, (max(levels) - min(levels)) / abs(level)


def linear_evidence(frames, exposures) -> str | None:
    """Why a bracket of 16-bit (or float) TIFFs is linear data, or None if it is not.

    A raw converter's linear TIFFs (``dcraw -4 -T``, ``selfcal linearize``) look like
    rendered 16-bit frames, but their response is the identity: calibrated as rendered
    frames without exposure times, the exponential ambiguity (Lin et al. 2011, §5) is
    resolved by the basis prior, which bends the curve (f⁻¹ at 1/8 of full scale 0.07
    instead of 0.125) and gets the exposure ratios wrong.  They are linear when a tag says
    so (PhotometricInterpretation LinearRaw, as in DNG), or when the pixel ratio between
    frames is the same at every brightness (:data:`LINEAR_RATIO_SPREAD`) and, where
    exposures are known, equals the exposure ratio (to the power 1 ±
    :data:`LINEAR_EXPONENT_TOLERANCE`).  This test is ours.  Without times, a rendered
    curve that is a pure power law passes it too: such frames are indistinguishable from
    linear data up to that ambiguity, and giving their times decides.

    Parameters
    ----------
    frames : sequence of path
    exposures : sequence of float or None
        Exposure per frame (EXIF time × ISO / N², or given), None where unknown.

    Returns
    -------
    str or None
        The evidence, in words, when every frame is a 16-bit or float TIFF and the
        bracket is linear; None otherwise.
    """
    frames = [Path(p) for p in frames]
    if len(frames) < 2 or not all(p.suffix.lower() in TIFF_SUFFIXES and is_linear_tiff(p)
                                  for p in frames):
        return None
    if all(_photometric_linear_raw(p) for p in frames):
        return "their TIFF tags say linear raw data (PhotometricInterpretation LinearRaw)"
    try:
        greys = [_grey_thumbnails(p) for p in frames]
    except InputError:      # e.g. float TIFFs: said where the frames are read for the work
        return None
    if any(g[0].shape != greys[0][0].shape for g in greys):
        return None
    known = [(float(e), g) for e, g in zip(exposures, greys) if e is not None]
    timed = len({round(math.log(t), 2) for t, _ in known}) >= 2
    if timed:
        ordered = sorted(known, key=lambda x: x[0])
        pairs = [(a, b, math.log(tb / ta)) for (ta, a), (tb, b) in zip(ordered, ordered[1:])
                 if tb >= ta * LINEAR_MIN_EXPOSURE_RATIO]
    else:
        ordered = sorted(greys, key=lambda g: float(np.median(np.nan_to_num(g[1], nan=1.0))))
        pairs = [(a, b, None) for a, b in zip(ordered, ordered[1:])]
    profiles = [(prof, log_t) for a, b, log_t in pairs
                if (prof := _ratio_profile(a, b)) is not None]
    if not profiles or max(spread for (_, spread), _ in profiles) > LINEAR_RATIO_SPREAD:
        return None
    spread = max(spread for (_, spread), _ in profiles)
    same = (f"the pixel ratios between frames are the same at every brightness (within "
            f"{100 * spread:.0f}%)")
    if not timed:
        return same + " and no exposure times are known to check them against"
    power = float(np.median([level / log_t for (level, _), log_t in profiles]))
    if abs(power - 1.0) > LINEAR_EXPONENT_TOLERANCE:
        return None
    return same + f" and follow the exposure times (to the power {power:.2f})"
