"""The inputs of a calibration by role: rendered frames, RAW+rendered pairs, unpaired raws
(:func:`group_inputs`).

Part of the path choice of :mod:`selfcal.choose`, which re-exports :class:`InputGroups`
and :func:`group_inputs`.  Whether a bracket of 16-bit TIFFs is linear data is
:func:`selfcal.exposure.linear_evidence.linear_evidence`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..typing import PathLike
from ..io.images import IMAGE_SUFFIXES
from ..io.raw import RAW_SUFFIXES, TIFF_SUFFIXES, is_linear_tiff, is_raw_path

__all__ = ["InputGroups", "group_inputs", "RENDERED_SUFFIXES"]

RENDERED_SUFFIXES = frozenset(IMAGE_SUFFIXES)
#: Preference among rendered files of one name when pairing with a raw.
_RENDERED_PREFERENCE = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


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


def group_inputs(paths: Sequence[PathLike]) -> InputGroups:
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
