"""Lens falloff and handheld stacks that show it, with their truth.

:func:`random_vignetting` draws a plausible lens falloff (a :class:`selfcal.lens.Vignetting`,
[Goldman2010] Eq. 4); :func:`simulate_handheld_stack` shoots a stack the way a handheld
camera does: per frame the *scene radiance* is cropped through the frame's own similarity
transform (so no border is invented), multiplied by the lens falloff in *frame*
coordinates, then exposed, rendered and stored exactly as :func:`selfcal.sim.simulate_stack`
does.  (:func:`selfcal.sim.handheld` warps frames after rendering instead: right for
alignment tests, wrong for vignetting, which moves with the camera, not the scene.)

References
----------
[Goldman2010] D. B. Goldman, "Vignette and exposure calibration and compensation",
IEEE TPAMI 32(12), 2010.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..lens.vignetting import Vignetting
from .camera import CameraPipeline
from .encoding import FrameOutput
from .sensor import SensorModel
from .stacks import (SyntheticStack, check_scene, check_stack_args,
                     default_exposure_scale)

__all__ = ["random_vignetting", "simulate_handheld_stack", "frame_similarities",
           "vignetting_rms"]


def random_vignetting(seed: int, *, corner_stops: tuple[float, float] = (0.5, 2.0), max_offset: float = 0.08,
                      channel_spread: float = 0.08, aspect: float = 1.5) -> Vignetting:
    """A random, plausible lens falloff (ours): the simulator's truth.

    ``V(r) = 1 + k₁r² + k₂r⁴ + k₃r⁶`` ([Goldman2010], Eq. 4) with every ``kᵢ ≤ 0`` (so
    ``V`` falls monotonically), the shape drawn as Dirichlet weights of ``r², r⁴, r⁶``
    (green's; red's and blue's drawn close to it, Dirichlet of concentration 200),
    the optical centre off the image centre by up to ``max_offset`` (half-diagonal units)
    and the depth chosen so that green loses ``U(corner_stops)`` stops at the farthest
    corner; red and blue lose ``1 ± channel_spread`` times green's depth.

    Parameters
    ----------
    seed : int
    corner_stops : (float, float)
        Range of green's falloff at the farthest corner, stops.
    max_offset : float
        Largest offset of the optical centre in x and in y.
    channel_spread : float
        Relative spread of the channels' depths.
    aspect : float
        ``width / height`` of the frames.

    Returns
    -------
    Vignetting
        ``source="self"``, ``diagnostics={"truth": True, "seed": seed}``.

    Examples
    --------
    >>> v = random_vignetting(3)
    >>> bool(0.5 <= v.corner_stops()[1] <= 2.0)
    True
    """
    lo, hi = (float(s) for s in corner_stops)
    if not 0 < lo <= hi < 8:
        raise InputError(f"corner_stops must be 0 < low <= high < 8, not {corner_stops!r}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 3601]))
    centre = rng.uniform(-max_offset, max_offset, 2)
    half_w, half_h = aspect / math.hypot(aspect, 1.0), 1.0 / math.hypot(aspect, 1.0)
    r_far = max(math.hypot(sx * half_w - centre[0], sy * half_h - centre[1])
                for sx in (-1, 1) for sy in (-1, 1))
    stops = rng.uniform(lo, hi)
    coefficients = np.empty((3, 3))
    common = rng.dirichlet([2.0, 1.0, 0.5])
    for c, spread in enumerate((rng.uniform(-1, 1), 0.0, rng.uniform(-1, 1))):
        shape = common if c == 1 else rng.dirichlet(1.0 + 200.0 * common)
        depth = 1.0 - 2.0 ** (-stops * (1.0 + channel_spread * spread))
        powers = np.array([r_far ** 2, r_far ** 4, r_far ** 6])
        coefficients[c] = -depth * shape / float(shape @ powers)
    return Vignetting(coefficients, centre, source="self", aspect=float(aspect),
                      description=f"simulated lens falloff, seed {seed}",
                      diagnostics={"truth": True, "seed": int(seed)})


def frame_similarities(n_frames: int, frame_shape, *, shift: float, degrees: float,
                       reference: int, seed: int) -> list:
    """Per frame, the 3×3 similarity from frame pixel coordinates to the reference's (ours).

    The reference frame's is the identity; every other frame is turned by ``U(±degrees)``
    about its centre and moved by ``shift · U(0.85, 1)`` of the frame's width and height
    in a random direction.
    """
    h, w = frame_shape
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 3602]))
    out = []
    cx, cy = 0.5 * (w - 1), 0.5 * (h - 1)
    for k in range(n_frames):
        angle = math.radians(rng.uniform(-degrees, degrees))
        phi = rng.uniform(0, 2 * math.pi)
        amount = shift * rng.uniform(0.85, 1.0)
        if k == reference:
            out.append(np.eye(3))
            continue
        c, s = math.cos(angle), math.sin(angle)
        t = (cx + amount * w * math.cos(phi), cy + amount * h * math.sin(phi))
        m = np.array([[c, -s, t[0] - c * cx + s * cy], [s, c, t[1] - s * cx - c * cy],
                      [0, 0, 1.0]])
        out.append(m)
    return out


def _default_frame_shape(scene_shape, shift: float, degrees: float):
    hs, ws = scene_shape[:2]
    turn = math.sin(math.radians(degrees))
    grow = 1.0 + 2.0 * shift + 2.0 * turn * (1.0 + max(hs, ws) / min(hs, ws)) + 0.02
    return int(hs / grow) // 2 * 2, int(ws / grow) // 2 * 2


def simulate_handheld_stack(scene: np.ndarray, pipeline: CameraPipeline,
                            exposure_times: npt.ArrayLike, *,
                            frame_shape: tuple[int, int] | None = None,
                            vignetting: Vignetting | None = None, shift: float = 0.12,
                            degrees: float = 2.0, jitter: float = 0.03,
                            jpeg_quality: int | None = 90, seed: int = 0) -> SyntheticStack:
    """A handheld bracket through a vignetting lens, physically in that order (ours).

    Per frame ``j``: the scene radiance is resampled through the frame's similarity
    (:func:`frame_similarities`; bilinear, the frame lies inside the scene), multiplied by
    ``V`` at the frame's own pixels ([Goldman2010], Eq. 1: ``I = f(e V(x) L)``), then
    exposed, rendered and stored as :func:`selfcal.sim.simulate_stack` does
    (``SensorModel()``, ``FrameOutput()``, the default exposure scale on the reference
    frame's radiance).

    Parameters
    ----------
    scene : array_like
        ``HxWx3`` linear radiance, larger than the frames (e.g. :func:`make_scene`).
    pipeline : CameraPipeline
    exposure_times : sequence of float
        Nominal times (sorted ascending).  All equal: a panorama-like sequence.
    frame_shape : (int, int), optional
        ``(height, width)`` of the frames; default the largest that every frame's
        footprint leaves inside the scene.
    vignetting : Vignetting, optional
        The lens falloff; None for a perfect lens.
    shift : float
        Frame displacement, a fraction of its width (x) and height (y).
    degrees : float
        Largest rotation.
    jitter : float
        Relative shutter jitter.
    jpeg_quality : int or None
    seed : int

    Returns
    -------
    SyntheticStack
        With ``transforms`` (per frame, the 3×3 map from reference to frame pixel
        coordinates, the convention of :func:`selfcal.stack.align.estimate_alignment`),
        ``reference`` (the middle frame), ``vignetting`` and ``radiance`` the scene in the
        reference frame's coordinates.

    Raises
    ------
    InputError
        When a frame's footprint leaves the scene (the message says the size needed).
    """
    import cv2

    scene = check_scene(scene)
    output = FrameOutput()
    nominal = check_stack_args(pipeline, exposure_times, jitter, 1, jpeg_quality, output)
    h, w = (_default_frame_shape(scene.shape, shift, degrees) if frame_shape is None
            else (int(frame_shape[0]), int(frame_shape[1])))
    n = nominal.size
    reference = (n - 1) // 2
    to_ref = frame_similarities(n, (h, w), shift=shift, degrees=degrees,
                                reference=reference, seed=seed)
    hs, ws = scene.shape[:2]
    place = np.array([[1.0, 0, 0.5 * (ws - w)], [0, 1.0, 0.5 * (hs - h)], [0, 0, 1]])
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float).T
    for m in to_ref:
        xy = (place @ m @ corners)[:2]
        if xy.min() < 0 or xy[0].max() > ws - 1 or xy[1].max() > hs - 1:
            raise InputError(f"a {h}x{w} frame moved by {shift:.0%} and turned by "
                             f"{degrees}° leaves a {hs}x{ws} scene: give a larger scene or a "
                             "smaller frame_shape")
    fall = (np.ones((h, w, 3), np.float32) if vignetting is None
            else vignetting.map(h, w))
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    radiances = [cv2.warpAffine(scene, (place @ m)[:2], (w, h), flags=flags,
                                borderMode=cv2.BORDER_REPLICATE) for m in to_ref]
    exposure_scale = default_exposure_scale(radiances[reference], nominal)
    seqs = np.random.SeedSequence(seed).spawn(1 + n)
    true = nominal * (1.0 + np.random.default_rng(seqs[0]).uniform(-jitter, jitter, n))
    sensor = SensorModel()
    images, raws, encoded = [], [], []
    for i, t in enumerate(true):
        raw = sensor.expose(radiances[i] * fall, exposure_scale * float(t),
                            np.random.default_rng(seqs[1 + i]))
        codes, data = output.store(pipeline.render(raw), jpeg_quality)
        images.append(codes)
        raws.append(raw)
        encoded.append(data)
    use_jpeg = output.uses_jpeg(jpeg_quality)
    return SyntheticStack(
        images=images, exposure_times=nominal, true_exposures=true,
        radiance=radiances[reference], raws=raws, pipeline=pipeline, bit_depth=8,
        exposure_scale=exposure_scale, seed=seed,
        jpeg_quality=int(jpeg_quality) if use_jpeg and jpeg_quality is not None else None, jitter=float(jitter),
        jpeg_bytes=encoded if use_jpeg else None,
        chroma_subsampling=output.chroma_subsampling if use_jpeg else None,
        params={"shift": shift, "degrees": degrees},
        transforms=[np.linalg.inv(m) for m in to_ref], reference=reference,
        vignetting=vignetting)


def vignetting_rms(estimate: Vignetting | None, truth: Vignetting | None, height: int,
                   width: int) -> float:
    """RMS over the frame and channels of ``V_est / V_true − 1`` (ours; a missing model
    counts as ``V = 1``)."""
    ones = np.ones((height, width, 3))
    est = ones if estimate is None else estimate.map(height, width)
    tru = ones if truth is None else truth.map(height, width)
    return float(np.sqrt(np.mean((est / tru - 1.0) ** 2)))

