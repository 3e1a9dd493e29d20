"""Finding the bracketed sessions in a photo library: EXIF, camera bodies, sessions.

A card dump holds every frame flat in ``DCIM/100XXXXX``-like folders; which frames form a
bracket is in their EXIF.  :func:`discover` walks the folders, reads each frame's EXIF
(:func:`read_frame_info`: make, model, body serial, lens, DateTimeOriginal with its
sub-seconds, exposure time, f-number, ISO, exposure bias, picture settings), pairs each
raw file with the rendered frame of the same stem, and groups the frames of each camera
into sessions (:func:`group_sessions`): consecutive shots, close in time, at exposures
that differ.  Files that fit no session are listed with the reason.

All of this is ours (the papers calibrate one given stack); the EXIF tags are those of
the EXIF 2.32 standard (CIPA DC-008).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from ..errors import InputError
from ..typing import PathLike
from ..io.images import IMAGE_SUFFIXES, effective_exposure_times
from ..io.raw import RAW_SUFFIXES
from .grouping import DEFAULT_MAX_GAP, SAME_EXPOSURE  # defined with the content grouping
from .grouping import GroupingRule

# EXIF 2.32 tags (IFD0 and the EXIF sub-IFD)
_EXIF_IFD = 0x8769
_TAGS = {
    "make": 0x010F, "model": 0x0110, "datetime": 0x0132,
    "exposure_time": 0x829A, "f_number": 0x829D, "iso": 0x8827,
    "datetime_original": 0x9003, "subsec_original": 0x9291,
    "exposure_bias": 0x9204, "shutter_apex": 0x9201,
    "custom_rendered": 0xA401, "exposure_mode": 0xA402, "white_balance": 0xA403,
    "contrast": 0xA408, "saturation": 0xA409, "sharpness": 0xA40A,
    "focal_length": 0x920A, "body_serial": 0xA431, "lens_make": 0xA433, "lens_model": 0xA434,
}
#: Picture settings that change the rendering (and so the response) when EXIF has them.
PICTURE_SETTINGS = ("custom_rendered", "contrast", "saturation", "sharpness")


@dataclass(frozen=True)
class FrameInfo:
    """What EXIF (and the file) tell about one frame.

    Attributes
    ----------
    path : pathlib.Path
    raw : pathlib.Path or None
        The raw file of the same stem in the same folder, if any.
    make, model, serial, lens : str
        Empty where EXIF has none.
    time : float or None
        Capture time (DateTimeOriginal + SubSecTimeOriginal) as seconds on the camera's
        clock (a naive timestamp), or the file's modification time when EXIF has none.
    time_source : str
        ``"exif"`` or ``"mtime"``.
    exposure_time, f_number, iso, exposure_bias : float or None
    size : tuple
        ``(width, height)``.
    kind : str
        ``"jpeg"``, ``"png"`` or ``"tiff"``.
    settings : tuple
        ``(name, value)`` of the :data:`PICTURE_SETTINGS` EXIF gives.
    bracketing : bool
        EXIF ExposureMode says auto bracket.
    focal_length : float or None
        Millimetres (EXIF FocalLength).
    """

    path: Path
    raw: Path | None
    make: str
    model: str
    serial: str
    lens: str
    time: float | None
    time_source: str
    exposure_time: float | None
    f_number: float | None
    iso: float | None
    exposure_bias: float | None
    size: tuple
    kind: str
    settings: tuple = ()
    bracketing: bool = False
    focal_length: float | None = None

    @property
    def relative_exposure(self) -> float | None:
        """``t · ISO/100 / N²`` (what pixel values scale with), None without a time."""
        if self.exposure_time is None:
            return None
        e = self.exposure_time
        if self.iso:
            e *= self.iso / 100.0
        if self.f_number:
            e /= self.f_number ** 2
        return e

    @property
    def camera(self) -> str:
        """The camera key: body and picture settings (see :func:`camera_key`)."""
        return camera_key(self)

    @property
    def camera_label(self) -> str:
        """``make model #serial`` as a person reads it."""
        label = " ".join(x for x in (self.make, self.model) if x) or "unknown camera"
        return label + (f" #{self.serial}" if self.serial else "")


def _text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    return str(value).replace("\x00", "").strip()


def _number(value) -> float | None:
    try:
        if isinstance(value, tuple):
            if len(value) == 2:
                num, den = value
                return float(num) / float(den) if den else None
            value = value[0] if value else None
        x = float(value)
    except (TypeError, ValueError, ZeroDivisionError, IndexError):
        return None
    return x if math.isfinite(x) else None


def _exif_time(date_text: str, subsec: str) -> float | None:
    """``YYYY:MM:DD HH:MM:SS`` plus sub-second digits as naive seconds, or None."""
    try:
        t = datetime.strptime(date_text.strip()[:19], "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    seconds = (t - datetime(1970, 1, 1)).total_seconds()
    digits = re.sub(r"\D", "", subsec or "")
    if digits:
        seconds += int(digits) / 10 ** len(digits)
    return seconds


def read_frame_info(path: PathLike, raw: PathLike | None = None) -> FrameInfo:
    """Read a rendered frame's EXIF: body, lens, capture time, exposure, picture settings.

    Never raises for missing tags; the capture time falls back to the file's modification
    time (``time_source = "mtime"``), the exposure time to the APEX ShutterSpeedValue.

    Raises
    ------
    InputError
        When the file cannot be opened as an image (the message names it).
    """
    return read_frame(path, raw)[0]


def read_frame(path, raw=None, also=None):
    """:func:`read_frame_info`, and ``also(image)`` on the same open image (the file
    opened and its EXIF parsed once; :mod:`.grouping` takes its thumbnail so).

    Returns
    -------
    (FrameInfo, what ``also`` returned or None)
    """
    from PIL import Image

    path = Path(path)
    extra = None
    try:
        with Image.open(path) as im:
            size = im.size
            fmt = (im.format or "").upper()
            ifd0 = im.getexif()
            sub = dict(ifd0.get_ifd(_EXIF_IFD))
            ifd0 = dict(ifd0)
            if also is not None:
                extra = also(im)
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except Exception as exc:  # Pillow raises several types for bad headers
        raise InputError(f"not an image file selfcal reads ({exc})", path) from None

    def tag(name):
        code = _TAGS[name]
        value = sub.get(code)
        return ifd0.get(code) if value is None else value

    time_text = _text(tag("datetime_original")) or _text(tag("datetime"))
    when = _exif_time(time_text, _text(tag("subsec_original"))) if time_text else None
    source = "exif"
    if when is None:
        when, source = path.stat().st_mtime, "mtime"
    exposure = _number(tag("exposure_time"))
    if exposure is None or exposure <= 0:
        apex = _number(tag("shutter_apex"))
        exposure = 2.0 ** (-apex) if apex is not None and abs(apex) < 64 else None
    settings = tuple((k, int(v)) for k in PICTURE_SETTINGS
                     if (v := _number(tag(k))) is not None)
    kind = {"JPEG": "jpeg", "PNG": "png", "TIFF": "tiff", "MPO": "jpeg"}.get(fmt, fmt.lower())
    positive = [_number(tag(k)) for k in ("f_number", "iso")]
    info = FrameInfo(
        path=path, raw=None if raw is None else Path(raw),
        make=_text(tag("make")), model=_text(tag("model")), serial=_text(tag("body_serial")),
        lens=_text(tag("lens_model")), time=when, time_source=source,
        exposure_time=exposure if exposure and exposure > 0 else None,
        f_number=positive[0] if positive[0] and positive[0] > 0 else None,
        iso=positive[1] if positive[1] and positive[1] > 0 else None,
        exposure_bias=_number(tag("exposure_bias")), size=tuple(size), kind=kind,
        settings=settings, bracketing=_number(tag("exposure_mode")) == 2,
        focal_length=_number(tag("focal_length")))
    return info, extra


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def camera_key(info: FrameInfo) -> str:
    """A file-name-safe key of the camera body and its picture settings.

    ``make-model-serial`` (serial where EXIF has it), the file kind (a camera's JPEG and
    its 16-bit TIFFs are different renderings), and a short hash of the picture
    settings when EXIF gives any: sessions that share a key share a response.  Frames
    without make and model are ``unknown-...``; they are never pooled.
    """
    body = "-".join(_slug(x) for x in (info.make, info.model, info.serial) if _slug(x))
    key = (body or "unknown") + f"-{info.kind}"
    if info.settings:
        digest = hashlib.sha1(repr(info.settings).encode()).hexdigest()[:6]
        key += f"-s{digest}"
    return key


@dataclass
class Session:
    """A bracketed session: consecutive frames of one camera at different exposures.

    Attributes
    ----------
    id : str
        ``camera-YYYYmmdd-HHMMSS-firststem``, unique in a library.
    camera : str
        :func:`camera_key` of its frames.
    frames : list of FrameInfo
        In capture order.
    reasons : list of str
        Why each frame is in it (:mod:`.grouping`, or the time rule).
    unsure : bool
        Some decision was by time alone or near a threshold (:mod:`.grouping`).
    """

    id: str
    camera: str
    frames: list
    reasons: list = field(default_factory=list)
    unsure: bool = False

    @property
    def paths(self) -> list:
        return [f.path for f in self.frames]

    @property
    def raws(self) -> list:
        return [f.raw for f in self.frames if f.raw is not None]

    @property
    def camera_label(self) -> str:
        return self.frames[0].camera_label

    @property
    def start(self) -> str:
        """Capture time of the first frame, ISO 8601 (camera clock)."""
        return _iso(self.frames[0].time)

    @property
    def exposure_times(self) -> list:
        """Exposure times scaled to the first timed frame's ISO and aperture (seconds):
        :func:`selfcal.io.effective_exposure_times`."""
        return effective_exposure_times(self.frames)


def _iso(t: float) -> str:
    """Naive seconds (see :attr:`FrameInfo.time`) as ISO 8601 with milliseconds."""
    from datetime import timedelta

    return (datetime(1970, 1, 1) + timedelta(seconds=t)).isoformat(timespec="milliseconds")


@dataclass
class Library:
    """What :func:`discover` found.

    Attributes
    ----------
    sessions : list of Session
        Ordered by camera, then time.
    unassigned : list of (pathlib.Path, str)
        Files in no session, with the reason.
    roots : list of pathlib.Path
    copies : list of (pathlib.Path, pathlib.Path)
        Files skipped as copies of another (:mod:`.copies`): ``(skipped, kept)``.
    lone_pairs : list of FrameInfo
        Frames in no session that have a raw beside them (single RAW+JPEG shots: each a
        scene of its camera's RAW-path library, :mod:`.raw_camera`); also in
        ``unassigned``.
    """

    sessions: list = field(default_factory=list)
    unassigned: list = field(default_factory=list)
    roots: list = field(default_factory=list)
    copies: list = field(default_factory=list)
    lone_pairs: list = field(default_factory=list)

    @property
    def cameras(self) -> dict:
        """Camera key → its sessions."""
        out: dict = {}
        for s in self.sessions:
            out.setdefault(s.camera, []).append(s)
        return out


def _walk(roots, exclude) -> list:
    """Every non-hidden file under the roots (sorted), skipping the excluded folders."""
    excluded = {Path(e).resolve() for e in exclude}
    files = []
    for root in roots:
        root = Path(root)
        if root.is_file():
            files.append(root.resolve())
            continue
        if not root.is_dir():
            raise InputError("no such folder" if not root.exists() else
                             "not a folder or a file", root)
        for folder, dirs, names in os.walk(root):
            here = Path(folder).resolve()
            dirs[:] = sorted(d for d in dirs if not d.startswith(".")
                             and (here / d).resolve() not in excluded)
            files += [here / n for n in sorted(names) if not n.startswith(".")]
    seen, out = set(), []
    for f in files:
        if f not in seen:
            seen.add(f)
            out.append(f)
    return out


def _pair_raws(files, unassigned):
    """``[(rendered, raw or None)]`` by folder and stem (case-insensitive); unpaired raws
    and files of other kinds go to ``unassigned`` with the reason."""
    rendered: dict[tuple[Path, str], Path] = {}
    raws: dict[tuple[Path, str], Path] = {}
    for f in files:
        suffix = f.suffix.lower()
        key = (f.parent, f.stem.lower())
        if suffix in IMAGE_SUFFIXES:
            if key in rendered:
                unassigned.append((f, f"a second rendered file of the name {f.stem} "
                                      f"(the batch uses {rendered[key].name})"))
                continue
            rendered[key] = f
        elif suffix in RAW_SUFFIXES:
            raws[key] = f
        else:
            unassigned.append((f, f"not an image file selfcal reads ({suffix or 'no suffix'})"))
    for key, raw in raws.items():
        if key not in rendered:
            unassigned.append((raw, f"raw file without a rendered image of the same name "
                                    f"({raw.stem}.JPG) in its folder"))
    return [(f, raws.get(key)) for key, f in rendered.items()]


def discover(roots: Sequence[PathLike], *, exclude: Sequence[PathLike] = (),
             max_gap: float = DEFAULT_MAX_GAP, by_content: bool = True,
             rule: GroupingRule | None = None, workers: int | None = None) -> Library:
    """Find the bracketed sessions under ``roots``.

    Parameters
    ----------
    roots : sequence of path
        Folders (walked recursively, hidden files and folders skipped) or files.
    exclude : sequence of path
        Folders not to walk (the batch's output folder).
    max_gap : float
        Seconds between the end of one frame and the start of the next beyond which a new
        session starts (:func:`group_sessions`); with ``by_content``, the gap within
        which time decides when thumbnails cannot be compared.
    by_content : bool
        Group by what the frames show, time as a hint (:func:`.grouping.group_by_content`);
        False: by time alone (:func:`group_sessions`).
    rule : GroupingRule, optional
        The content grouping's thresholds (``max_gap`` replaces its ``max_gap``).
    workers : int, optional
        Threads reading EXIF and thumbnails (default: up to 8, one per core).

    Frames that are copies of one file in several folders are used once, each session
    from one copy (:mod:`.copies`; the skipped copies are in :attr:`Library.copies` and
    the sessions' reasons).

    Returns
    -------
    Library

    Raises
    ------
    InputError
        A root that does not exist (named).
    """
    from .thumbnails import ThumbnailSpool

    roots = [Path(r) for r in roots]
    with ThumbnailSpool() as spool:
        return _discover(roots, exclude, max_gap, by_content, workers, rule, spool)


def _discover(roots, exclude, max_gap, by_content, workers, rule, spool):
    """:func:`discover` with its thumbnails in ``spool`` (a
    :class:`.thumbnails.ThumbnailSpool`)."""
    from dataclasses import replace

    from .copies import choose_copies, collapse_copies
    from .grouping import group_by_content
    from .thumbnails import read_frames

    unassigned: list = []
    infos, thumbs = [], []
    pairs = _pair_raws(_walk(roots, exclude), unassigned)
    read = read_frames(pairs, read_frame, workers=workers, thumbnails=by_content,
                       keep=spool.add)
    for (path, _), (info, thumb) in zip(pairs, read):
        if isinstance(info, InputError):
            unassigned.append((path, info.reason))
            continue
        if info.exposure_time is None:
            unassigned.append((path, "no exposure time in EXIF (sessions are found by "
                                     "their exposures)"))
            continue
        infos.append(info)
        thumbs.append(thumb)
    infos, thumbs, copies = collapse_copies(infos, thumbs)
    if by_content:
        rule = replace(rule or GroupingRule(), max_gap=max_gap)
        groups, loose = group_by_content(infos, lambda i: spool[thumbs[i]], rule)
        sessions = sessions_from_groups(groups)
    else:
        sessions, loose = group_sessions(infos, max_gap=max_gap)
    skipped = choose_copies(sessions, copies)
    unassigned += loose
    unassigned.sort(key=lambda x: str(x[0]))
    loose_paths = {p for p, _ in loose}
    lone = [f for f in infos if f.raw is not None and f.path in loose_paths]
    return Library(sessions=sessions, unassigned=unassigned, roots=roots, copies=skipped,
                   lone_pairs=lone)


def _starts_new(session: list, f: FrameInfo, max_gap: float) -> bool:
    """Whether frame ``f`` cannot join ``session`` (the frames so far, in time order)."""
    last = session[-1]
    if f.time - (last.time + (last.exposure_time or 0.0)) > max_gap:
        return True
    if f.size != last.size or f.lens != last.lens:
        return True
    e = f.relative_exposure
    return any(abs(math.log(e / g.relative_exposure)) < math.log(SAME_EXPOSURE)
               for g in session)


def group_sessions(frames: Sequence[FrameInfo], *, max_gap: float = DEFAULT_MAX_GAP
                   ) -> tuple[list[Session], list[tuple[Path, str]]]:
    """Group frames into bracketed sessions: per camera, consecutive in time.

    Per camera (:func:`camera_key`), frames are taken in capture order (ties by name); a
    frame joins the current session unless it starts more than ``max_gap`` seconds after
    the previous frame ended, differs in image size or lens, or repeats an exposure the
    session has (t · ISO / N² within 5 %: the next bracket began).  A session needs
    frames at two exposures at least; a lone frame is unassigned.

    Returns
    -------
    sessions : list of Session
    unassigned : list of (pathlib.Path, str)
    """
    by_camera: dict = {}
    for f in frames:
        by_camera.setdefault(f.camera, []).append(f)
    sessions, loose = [], []
    for camera in sorted(by_camera):
        ordered = sorted(by_camera[camera], key=lambda f: (f.time, f.path.name, str(f.path)))
        groups: list = []
        for f in ordered:
            if groups and not _starts_new(groups[-1], f, max_gap):
                groups[-1].append(f)
            else:
                groups.append([f])
        for g in groups:
            if len(g) < 2:
                loose.append((g[0].path, "a single frame: no other frame of its camera "
                                         f"within {max_gap:g} s at another exposure"))
                continue
            stamp = _iso(g[0].time)[:19].replace("-", "").replace(":", "").replace("T", "-")
            sid = f"{camera}-{stamp}-{_slug(g[0].path.stem)}"
            reasons = [f"{g[0].path.name}: starts a session (by time)"] + [
                f"{f.path.name}: {f.time - (p.time + (p.exposure_time or 0.0)):.1f} s after "
                f"the previous frame (<= {max_gap:g} s), an exposure the session has not"
                for p, f in zip(g, g[1:])]
            sessions.append(Session(id=sid, camera=camera, frames=g, reasons=reasons))
    ids = [s.id for s in sessions]
    for s in sessions:
        if ids.count(s.id) > 1:      # same camera, same second, same first name
            s.id += "-" + hashlib.sha1(str(s.frames[0].path).encode()).hexdigest()[:6]
    return sessions, loose


def sessions_from_groups(groups) -> list:
    """:class:`Session` objects for :class:`.grouping.ContentGroup` objects: ids as
    :func:`group_sessions` makes them (``camera-YYYYmmdd-HHMMSS-firststem``, a short
    hash added where two would be the same), reasons and doubt kept."""
    sessions = []
    for g in groups:
        f0 = g.frames[0]
        stamp = _iso(f0.time)[:19].replace("-", "").replace(":", "").replace("T", "-")
        sessions.append(Session(id=f"{f0.camera}-{stamp}-{_slug(f0.path.stem)}",
                                camera=f0.camera, frames=list(g.frames),
                                reasons=list(g.reasons), unsure=bool(g.unsure)))
    ids = [s.id for s in sessions]
    for s in sessions:
        if ids.count(s.id) > 1:
            s.id += "-" + hashlib.sha1(str(s.frames[0].path).encode()).hexdigest()[:6]
    return sessions
