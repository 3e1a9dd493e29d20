"""A simulated photo library with ground truth: card dumps of bracketed sessions.

For the batch's tests and benchmark: camera bodies (each a :class:`selfcal.sim`
pipeline, i.e. a known response), sessions of bracketed JPEGs of different scenes, with
the EXIF a camera writes (make, model, body serial, lens, DateTimeOriginal with
sub-seconds, exposure time, f-number, ISO, exposure bias, auto-bracket mode), all frames
flat in ``DCIM/1NN...`` folders of a fixed number of files each, as a card dump is.
Ours; the simulator is :func:`selfcal.sim.simulate_stack`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta
from fractions import Fraction
from pathlib import Path

import numpy as np

from .camera import CameraPipeline, default_pipeline
from ..io.images import exif_rational
from .encoding import jpeg_with_exif
from .scenes import make_scene
from .stacks import simulate_stack
from .tone import ToneCurve

#: The bracket of every simulated session (seconds), darkest first.
DEFAULT_TIMES = (1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0)


@dataclass
class SimulatedBody:
    """A camera body: what EXIF says of it, and the pipeline (its true response)."""

    make: str
    model: str
    serial: str
    lens: str
    pipeline: CameraPipeline
    prefix: str = "IMG_"

    def inverse_response(self, max_code: int = 255) -> np.ndarray:
        """The true f⁻¹ per channel at every code, ``(max_code + 1, 3)``."""
        return self.pipeline.inverse_response(np.arange(max_code + 1), max_code)


@dataclass
class SimulatedSession:
    """One written session: its body, frames (in shot order), truth."""

    body: SimulatedBody
    frames: list
    exposure_times: list
    start: datetime
    pipeline: object
    seed: int


@dataclass
class SimulatedLibrary:
    """What :func:`write_library` wrote."""

    root: Path
    sessions: list = field(default_factory=list)
    extra: list = field(default_factory=list)


def camera_exif(body: SimulatedBody, *, when: datetime, exposure_time: float,
                f_number: float = 8.0, iso: float = 100.0, bias: float = 0.0) -> bytes:
    """An EXIF block as a camera writes it for one frame of an auto bracket (piexif)."""
    import piexif

    stamp = when.strftime("%Y:%m:%d %H:%M:%S").encode()
    zeroth = {piexif.ImageIFD.Make: body.make.encode(),
              piexif.ImageIFD.Model: body.model.encode(),
              piexif.ImageIFD.DateTime: stamp}
    bias_r = Fraction(bias).limit_denominator(3)
    exif = {piexif.ExifIFD.ExposureTime: exif_rational(exposure_time),
            piexif.ExifIFD.FNumber: exif_rational(f_number, 100),
            piexif.ExifIFD.ISOSpeedRatings: int(round(iso)),
            piexif.ExifIFD.DateTimeOriginal: stamp,
            piexif.ExifIFD.SubSecTimeOriginal: f"{when.microsecond // 10000:02d}".encode(),
            piexif.ExifIFD.ExposureBiasValue: (bias_r.numerator, bias_r.denominator),
            piexif.ExifIFD.ExposureMode: 2,
            piexif.ExifIFD.BodySerialNumber: body.serial.encode(),
            piexif.ExifIFD.LensModel: body.lens.encode()}
    return piexif.dump({"0th": zeroth, "Exif": exif})


def default_bodies() -> list:
    """Two bodies of one make with different responses (film-like curves; sRGB)."""
    return [
        SimulatedBody("Simcam", "S1", "1001", "Simlens 35mm F2",
                      default_pipeline(seed=1), prefix="IMG_"),
        SimulatedBody("Simcam", "S2", "2002", "Simlens 50mm F1.8",
                      default_pipeline(curves=ToneCurve.gamma(2.2), seed=2),
                      prefix="DSC_"),
    ]


@dataclass(frozen=True)
class Shots:
    """What every session of :func:`write_library` shoots: frame size, bracket, JPEG quality.

    Attributes
    ----------
    height, width : int
        Frame size in pixels.
    times : tuple of float
        The bracket (seconds), darkest first.
    jpeg_quality : int
        Quality of the camera's JPEGs.
    """

    height: int = 128
    width: int = 192
    times: tuple = DEFAULT_TIMES
    jpeg_quality: int = 90


def write_session(root, body: SimulatedBody, counter: int, stack, when: datetime,
                   per_folder: int, mid: float) -> list:
    """Write one session's frames as the body's card files, in shot order, from frame
    number ``counter + 1``; each frame's EXIF says when it was shot and its exposure bias
    from the bracket's middle time ``mid``.  Returns the paths."""
    frames = []
    for i, t in enumerate(stack.exposure_times):
        n = counter + 1 + i
        folder = root / "DCIM" / f"{100 + (n - 1) // per_folder}SIMCM"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{body.prefix}{n:04d}.JPG"
        exif = camera_exif(body, when=when, exposure_time=float(t),
                           bias=round(float(np.log2(t / mid)) * 3) / 3)
        path.write_bytes(jpeg_with_exif(stack.jpeg_bytes[i], exif))
        frames.append(path)
        when += timedelta(seconds=float(t) + 0.3)
    return frames


def write_library(root, *, bodies=None, sessions_per_body: int = 3,
                  shots: Shots | None = None, per_folder: int = 12,
                  start=datetime(2024, 5, 1, 10, 0, 0), session_gap: float = 120.0,
                  seed: int = 0, pipelines=None) -> SimulatedLibrary:
    """Write a card dump of bracketed JPEG sessions, two or more bodies shooting in turn.

    Session ``k`` of body ``b`` starts at ``start + k·session_gap + b·7 s``; its frames
    are shot 0.3 s apart after the previous frame's exposure, with exposure bias
    ``log2(t / t_middle)``.  Frames are numbered per body (``IMG_0001.JPG``,
    ``DSC_0001.JPG``, ...) in shot order and filed ``per_folder`` at a time per body in
    ``DCIM/100SIMCM``, ``DCIM/101SIMCM``, ... (so sessions cross folders).

    Parameters
    ----------
    root : path
        Created if missing.
    bodies : list of SimulatedBody, optional
        Default :func:`default_bodies`.
    sessions_per_body : int
    shots : Shots, optional
        Frame size, bracket and JPEG quality of every session; default ``Shots()``
        (128 × 192, :data:`DEFAULT_TIMES`, quality 90).
    per_folder : int
        Frames per DCIM folder.
    start : datetime.datetime
        When the first session starts.
    session_gap : float
        Seconds between one round of sessions (one per body) and the next.
    seed : int
        Scenes and noise derive from it.
    pipelines : dict, optional
        ``(body index, session index) -> pipeline`` to render a session with another
        pipeline than its body's (a picture style EXIF does not tell).

    Returns
    -------
    SimulatedLibrary
    """
    root = Path(root)
    bodies = default_bodies() if bodies is None else list(bodies)
    shots = Shots() if shots is None else shots
    pipelines = pipelines or {}
    lib = SimulatedLibrary(root=root)
    counters = [0] * len(bodies)
    mid = float(np.sqrt(shots.times[0] * shots.times[-1]))
    for k in range(sessions_per_body):
        for b, body in enumerate(bodies):
            s_seed = seed * 1000 + 10 * k + b
            pipe = pipelines.get((b, k), body.pipeline)
            scene = make_scene(shots.height, shots.width, seed=s_seed)
            stack = simulate_stack(scene, pipe, list(shots.times), seed=s_seed,
                                   jpeg_quality=shots.jpeg_quality)
            when = start + timedelta(seconds=k * session_gap + 7 * b)
            frames = write_session(root, body, counters[b], stack, when, per_folder, mid)
            counters[b] += len(frames)
            lib.sessions.append(SimulatedSession(
                body=body, frames=frames,
                exposure_times=[float(t) for t in stack.exposure_times], start=when,
                pipeline=pipe, seed=s_seed))
    return lib
