"""A matrix of named simulator conditions: stacks that do not flatter a calibrator.

Each condition is a deterministic function ``(curve, seed) -> SyntheticStack`` built on
:mod:`selfcal.sim` (the pipeline ``P = f(Γ(M ρ))`` of [Gong2018], Eq. 1a).  What varies
from cell to cell:

* the scene (:func:`natural_scene`): ``neutral`` (every surface grey), ``colourful``
  (natural colours) or ``saturated`` (the same colours pushed to and past the gamut
  boundary), always a procedural outdoor layout with a colour chart, foliage, a sky
  gradient with clouds and the sun, skin-toned spheres and a long shadow ramp, with
  shading and texture;
* JPEG chroma subsampling 4:2:0 (OpenCV's default) or 4:4:4;
* in-camera sharpening (:class:`selfcal.sim.UnsharpMask`) on or off;
* one tone curve for all three channels, or a different one per channel;
* the smooth or the clip gamut map.

What every cell has: a camera colour matrix with white balance and highlight clip, shot
and read noise, ±3 % shutter jitter, six shots 1/250 … 1/8 s (the nominal times are what
a calibrator gets), JPEG quality drawn from the seed in 75 … 95.

Every random choice is drawn from the seed (``numpy.random.default_rng([seed, 15])``),
the same draws in every cell, so one seed gives the same scene, camera and JPEG quality in
all cells and two cells differ only in what their names say.  The sensor noise and the
shutter jitter come from :func:`selfcal.sim.simulate_stack` with the same seed.

The conditions, the scene and their parameters are ours: a measuring stick for the
calibrators, not a method from a paper.

Examples
--------
>>> from selfcal import sim
>>> from selfcal.sim.conditions import CONDITIONS
>>> cell = CONDITIONS["saturated/base"]
>>> stack = cell.simulate(sim.ToneCurve.srgb(), seed=1000, size=(64, 96))
>>> stack.condition, len(stack.images)
('saturated/base', 6)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .camera import LUMA, CameraPipeline, random_color_matrix
from .encoding import FrameOutput, UnsharpMask
from .scenes import unit_noise
from .stacks import DEMO_EXPOSURE_TIMES, SyntheticStack, simulate_stack
from .tone import ToneCurve

__all__ = ["SCENES", "Condition", "CONDITIONS", "natural_scene", "channel_curves",
           "ModelCamera"]

SCENES = ("neutral", "colourful", "saturated")
# chroma gain k of c' = Y + k (c - Y) per scene, and the floor (fraction of Y) it may reach
_CHROMA = {"neutral": 0.0, "colourful": 1.0, "saturated": 2.2}
_FLOOR = -0.04

# the ColorChecker Classic in 8-bit sRGB (X-Rite's published values), row by row
_CHART_SRGB = np.array([
    [115, 82, 68], [194, 150, 130], [98, 122, 157], [87, 108, 67], [133, 128, 177],
    [103, 189, 170], [214, 126, 44], [80, 91, 166], [193, 90, 99], [94, 60, 108],
    [157, 188, 64], [224, 163, 46], [56, 61, 150], [70, 148, 73], [175, 54, 60],
    [231, 199, 31], [187, 86, 149], [8, 133, 161], [243, 243, 242], [200, 200, 200],
    [160, 160, 160], [122, 122, 121], [85, 85, 85], [52, 52, 52]], dtype=np.float64)
_SKIN = np.array([[0.540, 0.305, 0.223], [0.352, 0.155, 0.091], [0.171, 0.084, 0.058]])
_LEAVES = np.array([[0.060, 0.160, 0.025], [0.180, 0.260, 0.030], [0.025, 0.090, 0.050]])
_FLOWERS = np.array([[0.55, 0.04, 0.04], [0.75, 0.55, 0.03], [0.50, 0.05, 0.35],
                     [0.70, 0.20, 0.02], [0.80, 0.80, 0.78], [0.20, 0.06, 0.45]])
_STRIPES = np.array([[0.35, 0.12, 0.06], [0.45, 0.32, 0.08], [0.10, 0.14, 0.25],
                     [0.10, 0.16, 0.05], [0.85, 0.85, 0.85], [0.30, 0.08, 0.20]])


def _srgb_to_linear(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _palette(colour: np.ndarray, k: float) -> np.ndarray:
    """``Y + k (c - Y)`` at constant Rec. 709 luminance ``Y``, floored at ``-0.04 Y``."""
    y = (colour @ LUMA)[..., None]
    return np.maximum(y + k * (colour - y), _FLOOR * y)


def _sky(yy, xx, aspect, rng, k):
    """Sky colour and log2 light: a zenith-to-horizon gradient, clouds, the sun's glow."""
    t = np.clip(yy / 0.3, 0.0, 1.0)[..., None]
    colour = (1 - t) * np.array([0.20, 0.38, 0.95]) + t * np.array([0.70, 0.80, 0.95])
    cloud = 1.0 / (1.0 + np.exp(-4.0 * (unit_noise(rng, yy.shape, max(yy.shape) / 12)
                                       - 0.6)))
    colour = _palette(colour, k) * (1 - cloud[..., None]) + cloud[..., None] * 0.9
    sx, sy = rng.uniform(0.7, 0.9), rng.uniform(0.05, 0.12)
    r = np.hypot((xx - sx) * aspect, yy - sy)          # in image heights
    glow = np.where(r < 0.02, 8.0, np.maximum(8.0 - 50.0 * (r - 0.02), 0.0))
    light = 0.6 * t[..., 0] + 0.5 * cloud + glow
    return colour, light


def _foliage(shape, rng, k):
    """Leaves: three greens mixed by smooth noise, leaf-scale texture and shade blobs;
    flowers (small discs, 1.5-4.5 px, of six colours) on about 12 % of it."""
    mix = np.stack([unit_noise(rng, shape, 4.0) for _ in range(3)], axis=-1)
    weights = np.exp(2.0 * mix)
    weights /= weights.sum(axis=-1, keepdims=True)
    colour = _palette(weights @ _LEAVES, k)
    shade = 1.0 / (1.0 + np.exp(-3.0 * (unit_noise(rng, shape, max(shape) / 6) - 0.3)))
    light = (0.4 + 1.1 * unit_noise(rng, shape, 2.5) + 0.4 * unit_noise(rng, shape, 0.8)
             - 4.0 * shade)
    h, w = shape
    flowers = _palette(_FLOWERS, k)
    for _ in range(int(0.12 * h * w / (np.pi * 3.0 ** 2))):
        r = rng.uniform(1.5, 4.5)
        cy, cx, which = rng.uniform(0, h), rng.uniform(0, w), rng.integers(len(_FLOWERS))
        y0, y1 = max(0, int(cy - r)), min(h, int(cy + r) + 1)
        x0, x1 = max(0, int(cx - r)), min(w, int(cx + r) + 1)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        disc = (yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2 <= r * r
        colour[y0:y1, x0:x1][disc] = flowers[which]
        light[y0:y1, x0:x1][disc] += 1.0
    return colour, light


def _chart(shape, rng, k):
    """A 4 × 6 ColorChecker on a dark board, light falling off across it, paper grain."""
    h, w = shape
    colour = np.full((h, w, 3), 0.04)
    ys = np.linspace(0, h, 5).round().astype(int)
    xs = np.linspace(0, w, 7).round().astype(int)
    gap = max(1, min(h // 4, w // 6) // 7)
    patches = _palette(_srgb_to_linear(_CHART_SRGB), k)
    for i in range(24):
        r, c = divmod(i, 6)
        colour[ys[r] + gap:ys[r + 1] - gap, xs[c] + gap:xs[c + 1] - gap] = patches[i]
    xx = np.linspace(0.0, 1.0, w)[None, :]
    light = (-0.2 - rng.uniform(1.0, 2.0) * xx + 0.04 * unit_noise(rng, (h, w), 0.7)
             + np.zeros((h, 1)))
    return colour, light


def _skin_spheres(shape, rng, k):
    """Three skin-toned spheres (Lambertian + a Phong highlight) before a tinted wall."""
    h, w = shape
    colour = np.broadcast_to(_palette(np.array([0.10, 0.18, 0.20]), k), (h, w, 3)).copy()
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    light = -2.0 - 1.5 * yy / h + 0.3 * unit_noise(rng, (h, w), 1.5)
    specular = np.zeros((h, w))
    ldir = np.array([-0.5, -0.6, 0.62])
    ldir /= np.linalg.norm(ldir)
    half = ldir + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    radius = 0.2 * min(h, w * 0.9)
    centres = [(0.25, 0.3), (0.5, 0.72), (0.78, 0.35)]
    for (cy, cx), skin in zip(centres, _SKIN):
        cy, cx = cy * h + rng.uniform(-0.03, 0.03) * h, cx * w + rng.uniform(-0.03, 0.03) * w
        dx, dy = (xx - cx) / radius, (yy - cy) / radius
        inside = dx * dx + dy * dy < 1.0
        nz = np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0.0, 1.0))
        lambert = np.clip(dx * ldir[0] + dy * ldir[1] + nz * ldir[2], 0.0, 1.0) + 0.03
        colour[inside] = _palette(skin, k)
        light[inside] = np.log2(lambert[inside]) + 0.05 * unit_noise(rng, (h, w), 0.6)[inside]
        spec = np.clip(dx * half[0] + dy * half[1] + nz * half[2], 0.0, 1.0) ** 40
        specular[inside] = 0.6 * spec[inside]
    return colour, light, specular


def _ground(shape, rng, k, stops):
    """Painted stripes under a light that falls off log-linearly over the whole range."""
    h, w = shape
    order = rng.permutation(len(_STRIPES))
    bands = np.linspace(0, h, len(order) + 1).round().astype(int)
    colour = np.empty((h, w, 3))
    for b, i in enumerate(order):
        colour[bands[b]:bands[b + 1]] = _palette(_STRIPES[i], k)
    xx = np.linspace(0.0, 1.0, w)[None, :]
    light = (0.3 - (stops + 0.3) * xx + 0.25 * unit_noise(rng, (h, w), 1.5)
             + 0.1 * unit_noise(rng, (h, w), 0.6))
    return colour, light


def natural_scene(height: int = 256, width: int = 384, *, palette: str = "colourful",
                  dynamic_range_stops: float = 14.0, seed: int = 0,
                  camera_from_output=None) -> np.ndarray:
    """A procedural outdoor scene: linear radiance, with shading, texture and highlights.

    Layout (fractions of the image): sky (top 30 %: a blue zenith-to-horizon gradient,
    clouds, the sun -- clipped in every frame -- and its glow, a smooth ramp to the
    highest codes); foliage (left third: three greens, leaf-scale texture, shade blobs
    4 stops down, small flowers of six colours); a ColorChecker Classic (middle: 24
    patches from X-Rite's sRGB values, light falling off 1-2 stops across it); three
    skin-toned spheres (right: Lambertian shading down to 5 stops, a Phong highlight
    each) before a tinted wall; painted stripes
    along the bottom (22 %) under a light that falls off log-linearly by
    ``dynamic_range_stops`` from left to right, so every channel of every colour runs
    through the whole range; a lens vignette (0.6 stops at the corners).

    ``palette`` sets the chroma of every surface at constant luminance ``Y`` (Rec. 709):
    ``c' = Y + k (c - Y)`` with ``k = 0`` (``"neutral"``: every surface grey), 1
    (``"colourful"``: the natural colours) or 2.2 (``"saturated"``: floored at ``-0.04 Y``,
    i.e. a little outside the output gamut, as saturated flowers, signs and skies are).
    Clouds, the sun and specular highlights stay white.

    Parameters
    ----------
    height, width : int
        At least 32 each.
    palette : str
        ``"neutral"``, ``"colourful"`` or ``"saturated"``.
    dynamic_range_stops : float
        Fall-off of the ground's light, in stops (the scene spans about 8 more: the sun,
        and dark reflectances in shadow).
    seed : int
    camera_from_output : array_like, optional
        3×3 matrix taking the scene's output-referred linear RGB to camera RGB (the inverse
        of the camera's colour step, so that the camera renders the scene's colours);
        default the identity.  Negative results are set to 0 (the sensor sees nothing
        there).

    Returns
    -------
    numpy.ndarray
        float32 ``(height, width, 3)`` camera RGB, non-negative; a white surface in full
        light is about 1.
    """
    h, w = int(height), int(width)
    if h < 32 or w < 32:
        raise InputError(f"the scene must be at least 32x32 pixels, got {h}x{w}")
    if palette not in _CHROMA:
        raise InputError(f"palette must be one of {SCENES}, got {palette!r}")
    stops = float(dynamic_range_stops)
    if not (np.isfinite(stops) and 1 <= stops <= 30):
        raise InputError(f"dynamic_range_stops must be in [1, 30], got {dynamic_range_stops!r}")
    k = _CHROMA[palette]
    rng = np.random.default_rng(seed)
    colour = np.empty((h, w, 3))
    light = np.empty((h, w))
    white = np.zeros((h, w))
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w], dtype=np.float64)[:, None, None]
    y1, y2, x1, x2 = int(0.3 * h), int(0.78 * h), int(0.34 * w), int(0.72 * w)

    colour[:y1], light[:y1] = _sky(yy[:y1], xx[:y1], w / h, rng, k)
    colour[y1:y2, :x1], light[y1:y2, :x1] = _foliage((y2 - y1, x1), rng, k)
    colour[y1:y2, x1:x2], light[y1:y2, x1:x2] = _chart((y2 - y1, x2 - x1), rng, k)
    c, l, s = _skin_spheres((y2 - y1, w - x2), rng, k)
    colour[y1:y2, x2:], light[y1:y2, x2:], white[y1:y2, x2:] = c, l, s
    colour[y2:], light[y2:] = _ground((h - y2, w), rng, k, stops)
    light -= 0.6 * ((2 * yy - 1) ** 2 + (2 * xx - 1) ** 2) / 2

    radiance = np.exp2(light)[..., None] * (colour + white[..., None])
    if camera_from_output is not None:
        m = np.asarray(camera_from_output, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise InputError(f"camera_from_output must be a finite 3x3 matrix, got {m.shape}")
        radiance = radiance @ m.T
    return np.maximum(radiance, 0.0).astype(np.float32)


def channel_curves(curve: ToneCurve, exponents) -> tuple:
    """Three tone curves from one: ``f_c(x) = f(x**p_c)**q_c`` per channel.

    ``exponents`` is ``((p_R, q_R), (p_G, q_G), (p_B, q_B))``; ``(1, 1)`` keeps ``f``.
    Each is monotone with ``f_c(0) = 0``, ``f_c(1) = 1`` (the same table, its axes
    raised to powers), so per-channel curves differ the way a camera's do: a little,
    smoothly, over the whole range (ours).
    """
    if not isinstance(curve, ToneCurve):
        raise InputError("channel_curves needs a ToneCurve")
    out = []
    for ch, (p, q) in enumerate(exponents):
        if p == 1 and q == 1:
            out.append(curve)
            continue
        if not (p > 0 and q > 0):
            raise InputError(f"channel exponents must be positive, got {(p, q)!r}")
        out.append(ToneCurve.from_table(curve.irradiance ** (1.0 / p), curve.brightness ** q,
                                        name=f"{curve.name} [{'RGB'[ch]}: p={p:.3f}, "
                                             f"q={q:.3f}]"))
    return tuple(out)


class ModelCamera:
    """Any camera model as a :func:`selfcal.sim.simulate_stack` pipeline.

    Parameters
    ----------
    render : callable
        Linear camera RGB ``(..., 3)`` -> rendered values in ``[0, 1]``, e.g. a real
        camera's in-camera model read from files (``selfcal.pipeline.nus``).
    inverse_table : array_like
        ``(256, 3)`` true ``f⁻¹`` per channel at codes 0 … 255 (the truth a calibrator is
        scored against), ``f⁻¹(255) = 1``.
    name : str
    """

    def __init__(self, render, inverse_table, name: str = "model camera"):
        table = np.asarray(inverse_table, dtype=np.float64)
        if table.shape != (256, 3) or not np.all(np.isfinite(table)):
            raise InputError(f"inverse_table must be a finite (256, 3) table, got {table.shape}")
        if not callable(render):
            raise InputError("render must be callable")
        self._render = render
        self.table = table
        self.name = str(name)

    def render(self, raw) -> np.ndarray:
        """Render linear camera RGB; float64 in ``[0, 1]``."""
        return np.clip(np.asarray(self._render(raw), dtype=np.float64), 0.0, 1.0)

    def inverse_response(self, codes, max_code: int = 255) -> np.ndarray:
        """The true ``f⁻¹`` at ``codes`` (linear interpolation in the table), ``(n, 3)``."""
        y = np.clip(np.asarray(codes, dtype=np.float64).ravel() / float(max_code), 0.0, 1.0)
        grid = np.arange(256) / 255.0
        return np.stack([np.interp(y, grid, self.table[:, c]) for c in range(3)], axis=1)

    def __repr__(self) -> str:
        return f"ModelCamera({self.name!r})"


@dataclass(frozen=True)
class Condition:
    """One cell of the benchmark matrix: a deterministic ``(curve, seed) -> SyntheticStack``.

    Attributes
    ----------
    name : str
        ``"<scene>/<variant>"``, e.g. ``"saturated/jpeg444"``.
    scene : str
        ``"neutral"``, ``"colourful"`` or ``"saturated"`` (:func:`natural_scene`).
    chroma_subsampling : str
        ``"4:2:0"`` or ``"4:4:4"``.
    sharpen : bool
        In-camera unsharp mask (amount 0.5 … 1.2, σ 0.8 … 1.5 px from the seed).
    per_channel : bool
        Different tone curves per channel (:func:`channel_curves`, ``p, q`` in
        0.9 … 1.1 for R and B from the seed; G keeps the given curve).
    gamut : str
        ``"smooth"`` or ``"clip"`` (:class:`selfcal.sim.CameraPipeline`).
    jitter : float
        Relative shutter jitter (uniform ±).
    quality : tuple of int
        JPEG quality range drawn from (inclusive).
    exposure_times : tuple of float
        Nominal shutter times (seconds).
    """

    name: str
    scene: str = "colourful"
    chroma_subsampling: str = "4:2:0"
    sharpen: bool = False
    per_channel: bool = False
    gamut: str = "smooth"
    jitter: float = 0.03
    quality: tuple = (75, 95)
    exposure_times: tuple = DEMO_EXPOSURE_TIMES

    def draw(self, seed: int) -> dict:
        """Everything the seed chooses (the same in every cell)."""
        rng = np.random.default_rng([int(seed), 15])
        return {
            "jpeg_quality": int(rng.integers(self.quality[0], self.quality[1] + 1)),
            "white_in_shortest": float(rng.uniform(0.25, 0.5)),
            "scene_seed": int(rng.integers(2 ** 31)),
            "matrix_seed": int(rng.integers(2 ** 31)),
            "matrix_strength": float(rng.uniform(0.5, 1.0)),
            "white_balance": (float(rng.uniform(1.6, 2.4)), 1.0, float(rng.uniform(1.2, 2.0))),
            "sharpen_amount": float(rng.uniform(0.5, 1.2)),
            "sharpen_sigma": float(rng.uniform(0.8, 1.5)),
            "channel_exponents": tuple((float(rng.uniform(0.9, 1.1)),
                                        float(rng.uniform(0.9, 1.1))) if c != 1 else (1.0, 1.0)
                                       for c in range(3)),
        }

    def pipeline(self, curve: ToneCurve, seed: int) -> CameraPipeline:
        """The cell's camera for ``seed``: colour matrix, white balance, gamut map, curves."""
        d = self.draw(seed)
        curves = channel_curves(curve, d["channel_exponents"]) if self.per_channel else curve
        matrix = random_color_matrix(d["matrix_seed"], d["matrix_strength"])
        return CameraPipeline(matrix=matrix, curves=curves, gamut=self.gamut,
                              white_balance=np.array(d["white_balance"]))

    def simulate(self, curve: ToneCurve, seed: int, *, size=(256, 384)) -> SyntheticStack:
        """The cell's stack for one tone curve and one seed.

        The scene is made in output-referred linear RGB and taken to camera RGB through the
        inverse of the camera's colour step (``diag(1/g) M⁻¹``), so that the camera renders
        the scene's colours; the shortest frame puts a white surface in full light at
        0.25 … 0.5 of raw white (from the seed), so the longest one clips it 3-4 stops
        over; noise, jitter and JPEG as :func:`selfcal.sim.simulate_stack`.
        """
        if not isinstance(curve, ToneCurve):
            raise InputError("a condition needs one ToneCurve (per-channel curves are made "
                             "from it)")
        d = self.draw(seed)
        pipe = self.pipeline(curve, seed)
        assert pipe.white_balance is not None   # a condition's camera has one
        camera_from_output = np.linalg.inv(pipe.matrix) / pipe.white_balance[:, None]
        h, w = size
        scene = natural_scene(h, w, palette=self.scene, seed=d["scene_seed"],
                              camera_from_output=camera_from_output)
        sharpening = (UnsharpMask(d["sharpen_amount"], d["sharpen_sigma"]) if self.sharpen
                      else None)
        scale = d["white_in_shortest"] / min(self.exposure_times)
        output = FrameOutput(chroma_subsampling=self.chroma_subsampling,
                             sharpening=sharpening)
        stack = simulate_stack(scene, pipe, self.exposure_times, jitter=self.jitter,
                               jpeg_quality=d["jpeg_quality"], output=output,
                               exposure_scale=scale, seed=int(seed))
        stack.condition = self.name
        stack.params = d
        return stack

    __call__ = simulate


def _matrix() -> dict:
    cells = [Condition("neutral/base", "neutral"),
             Condition("neutral/hard", "neutral", sharpen=True, per_channel=True)]
    for scene in ("colourful", "saturated"):
        cells += [Condition(f"{scene}/base", scene),
                  Condition(f"{scene}/jpeg444", scene, chroma_subsampling="4:4:4"),
                  Condition(f"{scene}/sharpened", scene, sharpen=True),
                  Condition(f"{scene}/per-channel", scene, per_channel=True),
                  Condition(f"{scene}/clip-gamut", scene, gamut="clip"),
                  Condition(f"{scene}/hard", scene, sharpen=True, per_channel=True)]
    return {c.name: c for c in cells}


#: The benchmark matrix, name -> :class:`Condition`.  ``base``: 4:2:0, no sharpening, one
#: curve, smooth gamut map; each other variant changes what its name says; ``hard``:
#: sharpened and per-channel curves together.  A neutral scene has no colours for the
#: chroma subsampling or the gamut map to act on, so it has only ``base`` and ``hard``.
CONDITIONS = _matrix()
