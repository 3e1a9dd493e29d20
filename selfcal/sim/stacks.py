"""Bracketed exposure stacks and RAW+JPEG pairs, with their ground truth.

A stack is a scene (:mod:`selfcal.sim.scenes`) exposed by the sensor
(:mod:`selfcal.sim.sensor`) at jittered shutter times, rendered by the pipeline
(:mod:`selfcal.sim.camera`) and stored as codes (:mod:`selfcal.sim.encoding`).
Everything the calibrators estimate is known here: the true per-channel inverse
response, the true (jittered) exposures, the colour matrix and the linear raws.
Tests, fixtures, benchmarks and ``selfcal demo`` are built on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError, OutputExistsError
from ..typing import PathLike
from .camera import CameraPipeline, default_pipeline
from .encoding import (FrameOutput, UnsharpMask, jpeg_round_trip, jpeg_with_exif,
                       png_with_exif, tiff_with_exif_tags)
from .scenes import make_scene
from .sensor import SensorModel

__all__ = ["SyntheticStack", "simulate_stack", "simulate_raw_jpeg_pair", "handheld",
           "demo_stack", "DEMO_EXPOSURE_TIMES"]

#: Nominal shutter times of :func:`demo_stack` (seconds), one stop apart (camera-rounded).
DEMO_EXPOSURE_TIMES = (1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8)


def _refuse_existing(paths, force: bool) -> None:
    """OutputExistsError for the first of ``paths`` that exists, unless ``force``."""
    for p in paths if not force else ():
        if p.exists():
            raise OutputExistsError(f"{p}: exists already (use --force to overwrite)")


@dataclass(eq=False)
class SyntheticStack:
    """A simulated bracketed exposure stack with its ground truth.

    Attributes
    ----------
    images : list of numpy.ndarray
        ``HxWx3`` RGB frames, uint8 (after the JPEG round trip when JPEG was on) or uint16.
    exposure_times : numpy.ndarray
        Nominal shutter times in seconds (what EXIF says), one per frame, ascending.
    true_exposures : numpy.ndarray
        Actual shutter times after jitter (what the sensor got), seconds.
    radiance : numpy.ndarray
        The scene (linear camera RGB).
    raws : list of numpy.ndarray
        float32 linear raw per frame in ``[0, 1]``, after noise and clipping.
    pipeline : CameraPipeline
    bit_depth : int
        8 or 16.
    exposure_scale : float
        ``radiance * exposure_scale * true_exposure`` is the sensor signal (1 = white).
    seed : int
    jpeg_quality : int or None
        JPEG quality of the frames (None: no JPEG).
    jitter : float
        Relative shutter jitter used.
    f_number, iso : float
        Written to EXIF by :meth:`write`.
    chroma_subsampling : str or None
        JPEG chroma subsampling of the frames (None: no JPEG).
    sharpening : UnsharpMask or None
        In-camera sharpening applied before quantisation and JPEG.
    condition : str or None
        Name of the benchmark condition that made the stack
        (:mod:`selfcal.sim.conditions`), else None.
    params : dict
        What a condition drew from its seed (JPEG quality, gains, ...), for reports.
    transforms : list of numpy.ndarray or None
        Handheld stacks (:func:`selfcal.sim.lens.simulate_handheld_stack`): per frame, the
        3×3 map from reference to frame pixel coordinates; ``radiance`` is then the scene
        in the reference frame's coordinates.  None: the frames did not move.
    reference : int or None
        The reference frame of ``transforms``.
    vignetting : Vignetting or None
        The lens falloff the frames went through (the truth), None for none.
    jpeg_bytes : list of bytes or None
        Each frame's JPEG file as the simulated camera encoded it (no EXIF block; it
        decodes to exactly the frame of :attr:`images`); None when the frames went
        through no JPEG.  :meth:`write` and the simulated cards write these bytes.
    """

    images: list
    exposure_times: np.ndarray
    true_exposures: np.ndarray
    radiance: np.ndarray
    raws: list
    pipeline: CameraPipeline
    bit_depth: int
    exposure_scale: float
    seed: int
    jpeg_quality: int | None = None
    jitter: float = 0.0
    f_number: float = 8.0
    iso: float = 100.0
    jpeg_bytes: list | None = field(default=None, repr=False)
    chroma_subsampling: str | None = None
    sharpening: UnsharpMask | None = None
    condition: str | None = None
    params: dict = field(default_factory=dict)
    transforms: list | None = None
    reference: int | None = None
    vignetting: Any = None

    def __len__(self) -> int:
        return len(self.images)

    @property
    def max_code(self) -> int:
        """The largest code value: 255 or 65535."""
        return 255 if self.bit_depth == 8 else 65535

    def inverse_response(self, codes: npt.ArrayLike | None = None) -> np.ndarray:
        """The true inverse response at ``codes`` (default: all codes ``0..max_code``).

        Returns
        -------
        numpy.ndarray
            ``(n, 3)`` float64, ``f_c^-1(code / max_code)`` (see
            :meth:`CameraPipeline.inverse_response`).
        """
        if codes is None:
            codes = np.arange(self.max_code + 1)
        return self.pipeline.inverse_response(codes, self.max_code)

    def write(self, folder: PathLike, *, fmt: str = "jpg", jpeg_quality: int = 95,
              force: bool = False,
              prefix: str = "frame") -> list[Path]:
        """Write the frames as image files with their nominal exposure data.

        Files are named ``{prefix}_{i:02d}.{fmt}`` and written atomically; nothing else is
        written.  JPEG frames that went through the JPEG round trip are written from their
        encoded bytes, with an EXIF block (ExposureTime = nominal time, FNumber, ISO)
        inserted, so they decode to exactly :attr:`images`.  PNG files carry the same EXIF
        in an ``eXIf`` chunk; TIFF files carry the three tags in IFD0 (TIFF/EP style).
        PNG and TIFF are lossless (16-bit for a 16-bit stack).

        Parameters
        ----------
        folder : str or os.PathLike
            Created if missing.
        fmt : str
            ``"jpg"``, ``"png"`` or ``"tif"``.
        jpeg_quality : int
            Used only for ``fmt="jpg"`` on a stack simulated without JPEG (then the files
            are a lossy copy of :attr:`images`; write PNG for an exact one).
        force : bool
            Allow replacing existing files.
        prefix : str

        Returns
        -------
        list of pathlib.Path

        Raises
        ------
        OutputExistsError
            When a target file exists and ``force`` is false (nothing is written then).
        InputError
            For an unknown format, or JPEG output of a 16-bit stack.
        """
        from ..io.images import exif_bytes, write_bytes_atomic, write_image

        ext = {"jpg": "jpg", "jpeg": "jpg", "png": "png", "tif": "tif",
               "tiff": "tif"}.get(str(fmt).lower().lstrip("."))
        if ext is None:
            raise InputError(f"unsupported stack output format {fmt!r} (jpg, png or tif)")
        if ext == "jpg" and self.bit_depth != 8:
            raise InputError("JPEG is 8-bit: write a 16-bit stack as png or tif")
        folder = Path(folder)
        digits = max(2, len(str(len(self.images) - 1)))
        paths = [folder / f"{prefix}_{i:0{digits}d}.{ext}" for i in range(len(self.images))]
        _refuse_existing(paths, force)
        for i, (path, image) in enumerate(zip(paths, self.images)):
            t = float(self.exposure_times[i])
            meta: dict[str, Any] = {"exposure_time": t, "f_number": self.f_number,
                                    "iso": self.iso}
            if ext == "jpg" and self.jpeg_bytes is not None:
                data = jpeg_with_exif(self.jpeg_bytes[i], exif_bytes(**meta))
                write_bytes_atomic(path, data, force=force)
            elif ext == "jpg":
                write_image(path, image, force=force, jpeg_quality=jpeg_quality,
                            exposure_time=t, f_number=self.f_number, iso=self.iso)
            elif ext == "png":
                from ..io.images import encode_image

                data = png_with_exif(encode_image(image, ".png"), exif_bytes(**meta))
                write_bytes_atomic(path, data, force=force)
            else:
                write_bytes_atomic(path, tiff_with_exif_tags(image, t, self.f_number,
                                                              self.iso), force=force)
        return paths

    def write_raws(self, folder: PathLike, *, with_times: bool = True, force: bool = False,
                   prefix: str = "raw") -> list[Path]:
        """Write the frames' linear raws as 16-bit TIFFs, as a raw converter does
        (``dcraw -4 -T``: no tone curve, black at 0, white = 65535).

        Files are ``{prefix}_{i}.tif``, written atomically; with ``with_times`` they
        carry the nominal ExposureTime, FNumber and ISO in IFD0, else no exposure data
        (many converters drop it).

        Returns
        -------
        list of pathlib.Path
            The raw TIFFs, in frame order.

        Raises
        ------
        OutputExistsError
            When a target file exists and ``force`` is false (nothing is written then).
        """
        from ..io.images import write_bytes_atomic

        folder = Path(folder)
        paths = [folder / f"{prefix}_{i}.tif" for i in range(len(self.raws))]
        _refuse_existing(paths, force)
        for i, (path, raw) in enumerate(zip(paths, self.raws)):
            codes = np.round(np.clip(raw, 0.0, 1.0) * 65535).astype(np.uint16)
            meta = ((float(self.exposure_times[i]), self.f_number, self.iso) if with_times
                    else (None, None, None))
            write_bytes_atomic(path, tiff_with_exif_tags(codes, *meta), force=force)
        return paths


def check_scene(scene) -> np.ndarray:
    """The scene as a float ``HxWx3`` array (InputError when it is not a non-negative one)."""
    scene = np.asarray(scene)
    if scene.ndim != 3 or scene.shape[2] != 3:
        raise InputError(f"the scene must be an HxWx3 array, got shape {scene.shape}")
    if not np.issubdtype(scene.dtype, np.floating):
        scene = scene.astype(np.float32)
    if not np.all(np.isfinite(scene)) or scene.min() < 0:
        raise InputError("the scene radiance must be finite and non-negative")
    return scene


def check_stack_args(pipeline, exposure_times, jitter, repeats, jpeg_quality,
                      output) -> np.ndarray:
    """Validate :func:`simulate_stack`'s arguments; return the sorted nominal times."""
    if not (callable(getattr(pipeline, "render", None))
            and callable(getattr(pipeline, "inverse_response", None))):
        raise InputError("pipeline must be a CameraPipeline (see default_pipeline), or an "
                         "object with render(raw) and inverse_response(codes, max_code)")
    times = np.asarray(exposure_times, dtype=np.float64).ravel()
    if times.size == 0 or not np.all(np.isfinite(times)) or np.any(times <= 0):
        raise InputError("exposure_times must be a non-empty sequence of positive numbers")
    if not (0.0 <= float(jitter) < 1.0):
        raise InputError(f"jitter must be in [0, 1), got {jitter!r}")
    if int(repeats) != repeats or repeats < 1:
        raise InputError(f"repeats must be a positive integer, got {repeats!r}")
    if jpeg_quality is not None and not (0 <= int(jpeg_quality) <= 100):
        raise InputError(f"jpeg_quality must be in [0, 100], got {jpeg_quality!r}")
    if not isinstance(output, FrameOutput):
        raise InputError("output must be a FrameOutput or None")
    return np.repeat(np.sort(times), int(repeats))


def default_exposure_scale(scene: np.ndarray, nominal: np.ndarray) -> float:
    """The scale that exposes the scene's median luminance at raw mid-grey 0.18 in the
    frame in the middle of the bracket (geometric mean of the extreme times)."""
    median = float(np.median(scene.mean(axis=2, dtype=np.float64)))
    if median <= 0:
        raise InputError("the scene's median radiance is zero; give exposure_scale")
    return 0.18 / (median * math.sqrt(nominal[0] * nominal[-1]))


def simulate_stack(scene: np.ndarray, pipeline: CameraPipeline, exposure_times: npt.ArrayLike, *,
                   jitter: float = 0.03, repeats: int = 1,
                   sensor: SensorModel | None = None, jpeg_quality: int | None = 90,
                   output: FrameOutput | None = None, exposure_scale: float | None = None,
                   seed: int = 0) -> SyntheticStack:
    """Simulate a bracketed exposure stack through ``P = f(Γ(M ρ))``.

    Per frame: ``ρ = sensor.expose(scene, exposure_scale * true_time)`` (noise, black and
    white clipping), ``P = pipeline.render(ρ)`` ([Gong2018], Eq. 1a), then
    ``output.store(P, jpeg_quality)``: optionally in-camera sharpening of ``P``, codes
    ``round(P * max_code)``, then (8-bit only) a JPEG round trip through OpenCV.  The
    shutter jitter and the unknown exposure ratios it causes are those discussed by
    [Lin2011] §4-5.

    Parameters
    ----------
    scene : array_like
        ``HxWx3`` linear radiance in camera RGB (e.g. :func:`make_scene`).
    pipeline : CameraPipeline
        Or any object with ``render(raw)`` (linear camera RGB -> rendered ``[0, 1]``) and
        ``inverse_response(codes, max_code)`` (the truth, ``(n, 3)``), e.g. a real
        camera's model read from files.
    exposure_times : sequence of float
        Nominal shutter times in seconds; frames are ordered by time (ascending).
    jitter : float
        Shutter inaccuracy: ``true = nominal * (1 + U(-jitter, jitter))`` per shot,
        independently (uniform ±jitter), ``0 <= jitter < 1``.
    repeats : int
        Each nominal time is shot ``repeats`` times (independent jitter and noise).
    sensor : SensorModel, optional
        Default ``SensorModel()`` (shot + read noise); ``SensorModel.ideal()`` is noise-free.
    jpeg_quality : int or None
        OpenCV JPEG quality for 8-bit stacks; None: no JPEG.  Ignored for 16-bit stacks.
    output : FrameOutput, optional
        Bit depth (8 or 16), JPEG chroma subsampling and in-camera sharpening; default
        ``FrameOutput()``: 8 bits, 4:2:0, no sharpening.
    exposure_scale : float, optional
        Default: ``0.18 / (median(scene luminance) * sqrt(t_min * t_max))`` -- the frame in
        the middle of the bracket (geometric mean of the extreme times) exposes the scene's
        median luminance (mean over channels) at raw mid-grey 0.18.  On a 14-stop scene a
        1/250 .. 1/8 s bracket then clips highlights in the longest frame and leaves the
        shadows deep in noise in the shortest.
    seed : int
        Everything random derives from ``numpy.random.SeedSequence(seed)``.

    Returns
    -------
    SyntheticStack

    Examples
    --------
    A 16-bit stack, 4:4:4 and sharpening are :class:`FrameOutput` settings:

    >>> from selfcal import sim
    >>> out = sim.FrameOutput(bit_depth=16)
    >>> stack = sim.simulate_stack(sim.make_scene(32, 48), sim.default_pipeline(),
    ...                            [0.01, 0.04], output=out)
    >>> stack.images[0].dtype, stack.max_code
    (dtype('uint16'), 65535)
    """
    scene = check_scene(scene)
    output = FrameOutput() if output is None else output
    nominal = check_stack_args(pipeline, exposure_times, jitter, repeats, jpeg_quality,
                                output)
    jitter = float(jitter)
    sensor = SensorModel() if sensor is None else sensor
    if exposure_scale is None:
        exposure_scale = default_exposure_scale(scene, nominal)
    exposure_scale = float(exposure_scale)
    if not (np.isfinite(exposure_scale) and exposure_scale > 0):
        raise InputError(f"exposure_scale must be positive, got {exposure_scale!r}")

    seqs = np.random.SeedSequence(seed).spawn(1 + nominal.size)
    shutter = np.random.default_rng(seqs[0])
    true = nominal * (1.0 + shutter.uniform(-jitter, jitter, nominal.size))
    use_jpeg = output.uses_jpeg(jpeg_quality)

    images, raws, encoded = [], [], []
    for i, t in enumerate(true):
        raw = sensor.expose(scene, exposure_scale * float(t), np.random.default_rng(seqs[1 + i]))
        codes, data = output.store(pipeline.render(raw), jpeg_quality)
        encoded.append(data)
        raws.append(raw)
        images.append(codes)
    return SyntheticStack(images=images, exposure_times=nominal, true_exposures=true,
                          radiance=scene, raws=raws, pipeline=pipeline,
                          bit_depth=output.bit_depth, exposure_scale=exposure_scale,
                          seed=seed,
                          jpeg_quality=(int(jpeg_quality) if use_jpeg and jpeg_quality is not None
                                        else None),
                          jitter=jitter, jpeg_bytes=encoded if use_jpeg else None,
                          chroma_subsampling=output.chroma_subsampling if use_jpeg else None,
                          sharpening=output.sharpening)


def simulate_raw_jpeg_pair(scene: np.ndarray | None = None,
                           pipeline: CameraPipeline | None = None, *, exposure: float = 1.0,
                           sensor: SensorModel | None = None,
                           jpeg_quality: int | None = 95, seed: int = 0,
                           raw_bits: int | None = 16) -> dict:
    """Simulate one RAW+JPEG pair, the input of the rank-based (RAW) calibration path.

    ``raw = sensor.expose(scene, exposure)`` (quantised to ``raw_bits`` like an ADC), and
    ``rendered = JPEG(round(255 f(Γ(M raw))))`` -- [Gong2018], Eq. 1a.

    Parameters
    ----------
    scene : array_like, optional
        Default: ``make_scene(dynamic_range_stops=8, saturation=0.6, seed=seed)`` -- a
        range a single exposure covers, with saturated colours for the gamut mapping.
    pipeline : CameraPipeline, optional
        Default ``default_pipeline(seed=seed)``.
    exposure : float
        Radiance-to-signal factor (scene white = 1, so 1 puts white at raw white).
    sensor : SensorModel, optional
        Default ``SensorModel()``.
    jpeg_quality : int or None
        None: no JPEG (``rendered`` are the quantised codes).
    seed : int
    raw_bits : int or None
        Quantise the raw to this many bits (16 makes a 16-bit TIFF of it exact); None: keep
        float.

    Returns
    -------
    dict
        ``raw`` (float32 ``HxWx3`` linear camera RGB in ``[0, 1]``), ``rendered`` (uint8 RGB
        after JPEG), ``codes`` (uint8 before JPEG), ``encoded`` (the JPEG bytes or None),
        ``pipeline``, ``radiance``, ``exposure``.
    """
    scene = (make_scene(dynamic_range_stops=8.0, saturation=0.6, seed=seed)
             if scene is None else check_scene(scene))
    pipeline = default_pipeline(seed=seed) if pipeline is None else pipeline
    sensor = SensorModel() if sensor is None else sensor
    raw = sensor.expose(scene, exposure, np.random.default_rng(np.random.SeedSequence(seed)))
    if raw_bits is not None:
        if not (1 <= int(raw_bits) <= 24):
            raise InputError(f"raw_bits must be in [1, 24], got {raw_bits!r}")
        levels = float(2 ** int(raw_bits) - 1)
        raw = (np.round(raw.astype(np.float64) * levels) / levels).astype(np.float32)
    codes = np.round(pipeline.render(raw) * 255).astype(np.uint8)
    if jpeg_quality is not None:
        rendered, data = jpeg_round_trip(codes, jpeg_quality)
    else:
        rendered, data = codes, None
    return {"raw": raw, "rendered": rendered, "codes": codes, "encoded": data,
            "pipeline": pipeline, "radiance": scene, "exposure": float(exposure)}


def handheld(images: Sequence[np.ndarray], *, fraction: float = 0.02, degrees: float = 0.5,
             seed: int = 0) -> list:
    """The frames of a stack as a handheld camera would have taken them (ours).

    Every frame but the middle one is turned by up to ``±degrees`` about its centre and
    shifted by up to ``±fraction`` of the width in x and y (uniform, seeded), with
    reflected borders (``cv2.warpAffine``, bilinear): the misalignment a verdict or an
    alignment step must notice.

    Examples
    --------
    >>> frames = handheld(demo_stack().images, seed=1)
    >>> len(frames), frames[0].shape
    (6, (256, 384, 3))
    """
    import cv2

    rng = np.random.default_rng(seed)
    out = []
    for k, im in enumerate(images):
        if k == len(images) // 2:
            out.append(im)
            continue
        h, w = im.shape[:2]
        m = cv2.getRotationMatrix2D((w / 2, h / 2), rng.uniform(-degrees, degrees), 1.0)
        m[:, 2] += rng.uniform(-fraction, fraction, 2) * w
        out.append(cv2.warpAffine(im, m, (w, h), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REFLECT))
    return out


def demo_stack(seed: int = 0) -> SyntheticStack:
    """The built-in stack of ``selfcal demo``.

    Six shots at 1/250, 1/125, 1/60, 1/30, 1/15, 1/8 s with ±3 % shutter jitter of a
    384×256, 14-stop scene with moderate saturation (0.5), rendered by
    ``default_pipeline(gamut="smooth", seed=seed)`` and saved as JPEG quality 90.
    """
    scene = make_scene(256, 384, dynamic_range_stops=14.0, saturation=0.5, seed=seed)
    return simulate_stack(scene, default_pipeline(gamut="smooth", seed=seed),
                          DEMO_EXPOSURE_TIMES, jitter=0.03, jpeg_quality=90, seed=seed)

