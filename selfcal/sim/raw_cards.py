"""A simulated card of RAW+JPEG pairs: one camera body, many scenes, a DNG beside each JPEG.

For the RAW+JPEG library fit of the batch (:mod:`selfcal.batch.raw_camera`), its tests and
``python3 -m bench.batch_raw``.  Every scene is a short auto bracket (a session of the
batch) shot by one :class:`~selfcal.sim.cards.SimulatedBody`: per frame the camera JPEG
with its EXIF (:func:`selfcal.sim.cards.camera_exif`) and, of the same stem, a DNG of the
frame's linear raw (:func:`linear_dng`: LinearRaw, black 0, white 65535, which LibRaw
reads back exactly).  The JPEG is the body's pipeline ``P = f(Γ(M ρ))`` ([Gong2018]
Eq. 1a) of that raw (:func:`selfcal.sim.simulate_stack`).  Scenes differ in content, not
only in seed: they cycle through :data:`SCENE_KINDS` -- synthetic charts and ramps of
low and high chroma (:func:`selfcal.sim.make_scene`) and outdoor scenes of natural and
saturated colour (:func:`selfcal.sim.conditions.natural_scene`) -- so one scene's
colours do not cover another's, as on a real card.  Ours.
"""

from __future__ import annotations

import io as _io
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .cards import SimulatedBody, write_session, default_bodies
from .scenes import make_scene
from .stacks import simulate_stack

#: The scenes a card cycles through: ("ramps", chroma) or ("outdoor", palette).
SCENE_KINDS = (("ramps", 0.3), ("outdoor", "colourful"), ("ramps", 0.9),
               ("outdoor", "saturated"), ("ramps", 0.6), ("outdoor", "neutral"))
#: The bracket of every scene (seconds): two frames, two stops apart.
RAW_TIMES = (1 / 60, 1 / 15)


def linear_dng(raw: np.ndarray, *, make: str = "Simcam", model: str = "S1") -> bytes:
    """A LinearRaw DNG (DNG 1.4) of a linear ``HxWx3`` raw in ``[0, 1]``, 16-bit.

    PhotometricInterpretation LinearRaw (34892), BlackLevel 0, WhiteLevel 65535, an
    identity ColorMatrix1 and a neutral AsShotNeutral: LibRaw (``rawpy``) reads it as a
    demosaiced raw, and :func:`selfcal.io.raw.read_raw_linear` gives back
    ``round(65535 raw) / 65535``.  Written with ``tifffile``.
    """
    import tifffile

    codes = np.round(np.clip(np.asarray(raw, np.float64), 0.0, 1.0) * 65535).astype(np.uint16)
    unique = f"{make} {model}"
    tags = [(50706, "B", 4, (1, 4, 0, 0), True),            # DNGVersion
            (50707, "B", 4, (1, 1, 0, 0), True),            # DNGBackwardVersion
            (50708, "s", 0, unique, True),                  # UniqueCameraModel
            (271, "s", 0, make, True), (272, "s", 0, model, True),   # Make, Model
            (50714, "H", 1, 0, True),                       # BlackLevel
            (50717, "H", 1, 65535, True),                   # WhiteLevel
            (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),
            (50778, "H", 1, 21, True),                      # CalibrationIlluminant1: D65
            (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True)]     # AsShotNeutral
    out = _io.BytesIO()
    tifffile.imwrite(out, codes, photometric=34892, extratags=tags, metadata=None,
                     software=False)
    return out.getvalue()


def raw_card_scene(kind, height: int, width: int, seed: int) -> np.ndarray:
    """The radiance of one scene of :data:`SCENE_KINDS` (``kind``), drawn from ``seed``."""
    from .conditions import natural_scene

    what, value = kind
    if what == "ramps":
        return make_scene(height, width, dynamic_range_stops=8.0, saturation=float(value),
                          seed=seed)
    return natural_scene(height, width, palette=str(value), dynamic_range_stops=6.0,
                         seed=seed)


@dataclass
class RawCardScene:
    """One scene written: its frames (JPEG), raws (DNG, same stems) and what made them."""

    kind: tuple
    frames: list
    raws: list
    seed: int


@dataclass
class RawCard:
    """What :func:`write_raw_card` wrote: the body (its pipeline is the truth) and scenes."""

    root: Path
    body: SimulatedBody
    scenes: list = field(default_factory=list)


def write_raw_card(root, *, n_scenes: int = 10, body: SimulatedBody | None = None,
                   height: int = 96, width: int = 144, times=RAW_TIMES,
                   jpeg_quality: int = 92, seed: int = 0, lone: int = 0,
                   start=datetime(2024, 6, 1, 9, 0, 0)) -> RawCard:
    """Write a card dump of RAW+JPEG brackets of ``n_scenes`` scenes by one body.

    Scene ``k`` is :data:`SCENE_KINDS` ``[k mod 6]`` drawn from seed ``1000 seed + k``,
    shot at ``times`` (:func:`selfcal.sim.simulate_stack`, JPEG ``jpeg_quality``) two
    minutes after scene ``k - 1``; its frames are written as
    :func:`selfcal.sim.cards.write_library` writes them (``DCIM/1NNSIMCM``, EXIF of an
    auto bracket), each with its raw as ``<stem>.DNG`` (:func:`linear_dng`) beside it.
    The last ``lone`` of the scenes are single shots instead (the first time of ``times``
    alone): RAW+JPEG pairs in no bracket.

    Returns
    -------
    RawCard
    """
    root = Path(root)
    body = default_bodies()[0] if body is None else body
    card = RawCard(root=root, body=body)
    counter = 0
    mid = float(np.sqrt(times[0] * times[-1]))
    for k in range(int(n_scenes)):
        s_seed = 1000 * int(seed) + k
        kind = SCENE_KINDS[k % len(SCENE_KINDS)]
        scene = raw_card_scene(kind, height, width, s_seed)
        shot = list(times) if k < int(n_scenes) - int(lone) else list(times[:1])
        stack = simulate_stack(scene, body.pipeline, shot, seed=s_seed,
                               jpeg_quality=jpeg_quality)
        when = start + timedelta(seconds=120 * k)
        frames = write_session(root, body, counter, stack, when, 999, mid)
        counter += len(frames)
        raws = []
        for path, raw in zip(frames, stack.raws):
            dng = path.with_suffix(".DNG")
            dng.write_bytes(linear_dng(raw, make=body.make, model=body.model))
            raws.append(dng)
        card.scenes.append(RawCardScene(kind=kind, frames=frames, raws=raws, seed=s_seed))
    return card
