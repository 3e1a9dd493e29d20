"""Benchmark cells where the per-channel response model is exact: no colour matrix, no gamut.

The cells of :mod:`selfcal.sim.conditions` all put a colour matrix and a gamut map before
the tone curves, so a calibrator whose model is "one curve per channel" is there only
approximately right.  These cells apply the curves per channel directly to the noisy
sensor values (``P_c = f_c(clip(ρ_c))``): the model of [Debevec1997] and of Eq. 8
of [Lin2011] holds exactly, up to noise and JPEG.  What they measure is how well a
calibrator uses its data, not how it copes with colour processing.

Scene (:func:`voronoi_scene`): Voronoi patches over 12 stops, each with its own colour
(grey in ``neutral`` cells, up to fully saturated hues in ``saturated`` ones), a shading
gradient and a texture.  Stack: six shots 1/250 … 1/8 s, the brightest surface at 0.5 …
1 of raw white in the shortest (the longest then clips heavily), ±3 % shutter jitter,
shot and read noise (:class:`selfcal.sim.SensorModel`), JPEG quality 92 4:2:0 written
by OpenCV; one stack in three (drawn from the seed) has a different curve per channel
(:func:`selfcal.sim.conditions.channel_curves`).

The cells and the scene are ours, a measuring stick after the conditions described for
the held-out comparison against colour-hdri's Debevec; not a method from a paper.

Examples
--------
>>> from selfcal import sim
>>> from selfcal.sim.exact import EXACT_CONDITIONS
>>> stack = EXACT_CONDITIONS["exact/saturated"].simulate(
...     sim.ToneCurve.srgb(), seed=1000, size=(60, 80))
>>> len(stack.images), stack.images[0].shape
(6, (60, 80, 3))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .camera import CameraPipeline
from .conditions import channel_curves
from .encoding import FrameOutput
from .scenes import unit_noise
from .stacks import DEMO_EXPOSURE_TIMES, SyntheticStack, simulate_stack
from .tone import ToneCurve

__all__ = ["voronoi_scene", "ExactCondition", "EXACT_CONDITIONS"]

#: Patches of a Voronoi scene (the same layout at every frame size).
N_PATCHES = 160
#: Stops spanned by the patches' levels.
SCENE_STOPS = 12.0


def voronoi_scene(height: int, width: int, *, saturated: bool, seed: int,
                  n_patches: int = N_PATCHES, stops: float = SCENE_STOPS) -> np.ndarray:
    """Voronoi patches of random level, colour, shading and texture; linear camera RGB.

    Each patch: a log2 level uniform over ``stops`` (brightest 0), a linear shading
    gradient of up to ±0.75 stop across the frame's height in a random direction, and a
    texture of 0.12 stop (smooth noise of 1.5 % of the frame's height).  Colour: grey, or
    with ``saturated`` a random hue at HSV saturation uniform in 0 … 0.95.  The layout is in
    frame fractions, so one seed gives the same scene at every size.

    Returns
    -------
    numpy.ndarray
        float32 ``(height, width, 3)``, the brightest patch's brightest channel about 1.
    """
    from scipy.spatial import cKDTree

    h, w = int(height), int(width)
    if h < 16 or w < 16:
        raise InputError(f"the scene must be at least 16x16 pixels, got {h}x{w}")
    rng = np.random.default_rng([int(seed), 25])
    centres = rng.uniform(0, 1, (n_patches, 2)) * np.array([h, w])
    level = rng.uniform(-stops, 0.0, n_patches)
    angle = rng.uniform(0, 2 * np.pi, n_patches)
    slope = rng.uniform(0, 1.5, n_patches) / h       # stops per pixel
    if saturated:
        hue = rng.uniform(0, 1, n_patches)
        sat = rng.uniform(0, 0.95, n_patches)
        colour = _hsv_colours(hue, sat)
    else:
        colour = np.ones((n_patches, 3))
    yy, xx = np.mgrid[0:h, 0:w]
    _, label = cKDTree(centres).query(np.stack([yy.ravel(), xx.ravel()], axis=1) + 0.5)
    label = label.reshape(h, w)
    dy, dx = yy - centres[label, 0], xx - centres[label, 1]
    shade = slope[label] * (dy * np.sin(angle[label]) + dx * np.cos(angle[label]))
    texture = 0.12 * unit_noise(rng, (h, w), max(0.6, 0.015 * h))
    light = np.exp2(level[label] + shade + texture - 0.75)
    return (light[..., None] * colour[label]).astype(np.float32)


def _hsv_colours(hue: np.ndarray, sat: np.ndarray) -> np.ndarray:
    """RGB of HSV (hue, sat, value 1), shape (n, 3)."""
    k = (np.array([5.0, 3.0, 1.0])[None, :] + 6.0 * hue[:, None]) % 6.0
    return 1.0 - sat[:, None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


@dataclass(frozen=True)
class ExactCondition:
    """A cell with the per-channel model exact; ``simulate(curve, seed)`` as a Condition.

    Attributes
    ----------
    name : str
    scene : str
        ``"neutral"`` or ``"saturated"``.
    size : tuple of int
        Frame ``(H, W)``: the cell's own, whatever size the caller asks for.
    jpeg_quality : int
    jitter : float
    exposure_times : tuple of float
    """

    name: str
    scene: str = "saturated"
    size: tuple = (300, 400)
    jpeg_quality: int = 92
    jitter: float = 0.03
    exposure_times: tuple = DEMO_EXPOSURE_TIMES

    def draw(self, seed: int) -> dict:
        """Everything the seed chooses."""
        rng = np.random.default_rng([int(seed), 25, 1])
        return {
            "jpeg_quality": self.jpeg_quality,
            "white_in_shortest": float(rng.uniform(0.5, 1.0)),
            "scene_seed": int(rng.integers(2 ** 31)),
            "per_channel": bool(rng.uniform() < 1.0 / 3.0),
            "channel_exponents": tuple((float(rng.uniform(0.9, 1.1)),
                                        float(rng.uniform(0.9, 1.1))) if c != 1 else (1.0, 1.0)
                                       for c in range(3)),
        }

    def pipeline(self, curve: ToneCurve, seed: int) -> CameraPipeline:
        """Identity matrix, no white balance, the curves on the clipped raw values."""
        d = self.draw(seed)
        curves = channel_curves(curve, d["channel_exponents"]) if d["per_channel"] else curve
        return CameraPipeline(matrix=np.eye(3), curves=curves, gamut="none")

    def simulate(self, curve: ToneCurve, seed: int, *, size=None) -> SyntheticStack:
        """The cell's stack for one curve and one seed (``size`` overrides the cell's)."""
        if not isinstance(curve, ToneCurve):
            raise InputError("a condition needs one ToneCurve")
        d = self.draw(seed)
        h, w = self.size if size is None else size
        scene = voronoi_scene(h, w, saturated=self.scene == "saturated",
                              seed=d["scene_seed"])
        scale = d["white_in_shortest"] / min(self.exposure_times)
        stack = simulate_stack(scene, self.pipeline(curve, seed), self.exposure_times,
                               jitter=self.jitter, jpeg_quality=self.jpeg_quality,
                               seed=int(seed), exposure_scale=scale,
                               output=FrameOutput(chroma_subsampling="4:2:0"))
        stack.condition = self.name
        stack.params = d
        return stack

    __call__ = simulate


def _cells() -> dict:
    cells = []
    for scene in ("neutral", "saturated"):
        cells += [ExactCondition(f"exact/{scene}", scene, size=(300, 400)),
                  ExactCondition(f"exact/{scene}-1.5MP", scene, size=(1000, 1500))]
    return {c.name: c for c in cells}


#: The per-channel-exact cells, name -> :class:`ExactCondition`: neutral and saturated
#: Voronoi scenes at 300×400 and at 1.5 MP (1000×1500).
EXACT_CONDITIONS = _cells()
