r"""A generator of plausible camera response curves (the database behind the built-in basis).

The JPEG-only path models the inverse response in the log domain with a mean and a few
principal components, ``g(I) = log f^-1(I) = g0(I) + sum_n h_n(I) c_n`` (Lin, Kim, Süsstrunk
& Brown, *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §5,
Eq. 7).  Lin et al. take that PCA from Grossberg & Nayar's DoRF database (*What is the Space
of Camera Response Functions?*, CVPR 2003; *Modeling the Space of Camera Response
Functions*, PAMI 2004).  DoRF cannot be redistributed, so selfcal builds its own database
from what is *published* about how cameras, films and tone mappers encode light, and
computes the basis from it (``scripts/make_response_basis.py``).  DoRF is used only as an
out-of-sample benchmark (``python3 -m bench.basis``).

Every member is a *forward* response ``f``: normalised irradiance ``E`` in ``[0, 1]`` to
normalised brightness in ``[0, 1]``, monotone non-decreasing, with ``f(0) = 0`` and
``f(1) = 1`` (Grossberg & Nayar's normalisation), reaching white with a usable slope
(*White point* below).  An encoding defined on some other range
is normalised over the exposure range it is used on: ``f(E) = (F(x_max E) - F(0)) /
(F(x_max) - F(0))``, where ``x_max`` (how much scene light maps to white) is drawn at
random.

Families
--------
``gamma``
    Pure power laws ``f(E) = E^(1/gamma)``, ``gamma`` log-uniform in ``[0.9, 3.2]``: the
    classic CRT-matched encodings (1.8 Apple, 2.2 PC/NTSC, 2.4–2.6 broadcast and cinema).
``srgb``, ``rec709``, ``bt1886``
    Standard display-referred OETFs: IEC 61966-2-1 sRGB (linear segment 12.92 E below
    0.0031308, then ``1.055 E^(1/2.4) - 0.055``), ITU-R BT.709 (4.5 E below 0.018, then
    ``1.099 E^0.45 - 0.099``) and the inverse of the BT.1886 EOTF with a random black
    level.  Each is used over a random exposure range ``[0, x_max]``, ``x_max`` in
    ``[0.1, 1]``: a camera that leaves headroom uses only the lower part of the curve.
``slog2``, ``slog3``, ``logc3``, ``clog``, ``vlog``, ``flog``
    Published camera log encodings, as functions of scene reflectance (0.18 = mid grey):
    Sony S-Log2 and S-Log3 (Sony technical summaries), ARRI LogC3 at EI 800 (ARRI
    "ALEXA Log C curve" white paper), Canon Log (Cinema EOS white paper), Panasonic
    V-Log (V-Log/V-Gamut reference manual) and Fujifilm F-Log (F-Log data sheet),
    including their linear segments near black.  Normalised over a random reflectance
    range ``[0, x_max]``, ``x_max`` log-uniform in ``[0.3, 16]``.
``hd_negative``, ``hd_reversal``, ``log_logistic``
    Film.  A Hurter–Driffield characteristic curve gives density as a function of log
    exposure ``u = log10 H``: a fog level, a toe, a straight line of slope ``gamma_film``
    and a shoulder, written with two soft-plus functions,
    ``D(u) = D_min + gamma_film * [sp_s(u - u_toe) - sp_s(u - u_shoulder)]``.
    A negative that is scanned/printed gives brightness that grows with density
    (``hd_negative``: brightness ∝ ``D - D_min``, optionally passed through
    ``1 - 10^(-k D)`` print/opacity compression); a reversal (slide) film gives
    transmittance ``10^(-D)`` with ``D`` falling with exposure (``hd_reversal``), read by
    a scanner with its own encoding gamma.  ``log_logistic`` is the simplest sigmoid in log
    exposure, ``f ∝ E^n / (E^n + m^n)`` (Naka–Rushton form).
``reinhard``, ``hable``, ``aces``
    Filmic tone mappers followed by a display encoding: extended Reinhard
    ``L (1 + L / Lw^2) / (1 + L)`` with a random white point; Hable's "Uncharted 2" curve
    ``((x (A x + C B) + D E) / (x (A x + B) + D F)) - E / F`` with randomly scaled
    parameters and exposure range; Narkowicz's fit of the ACES RRT+ODT,
    ``x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)``.
``camera``
    What consumer cameras do to JPEGs: a base encoding (sRGB, Rec.709 or a gamma) used
    over a random exposure range, followed by a contrast "picture style" S-curve in the
    encoded domain, and usually a highlight roll-off.
``bernstein``, ``mixture``
    Monotone Bernstein polynomials (non-decreasing control values from 0 to 1, degree 3–8,
    biased towards concave curves) and convex mixtures of two or three other members.
    A convex combination of normalised monotone curves is again one.

Every member may then be modified (``modify_randomly``), as real processing does:
a *linear toe* near black (value-continuous linear segment, as sRGB/Rec.709 have), a
smooth *black offset* (flare or black-level subtraction: ``f(δ + (1-δ)E)`` renormalised,
which makes the curve nearly linear near black), a small *black crush* (a JPEG black
point above zero), a *soft shoulder* near white (exponential roll-off above a knee,
applied to the output or to the exposure), output/input *powers*, and a smooth random
*warp* ``w(y) = y + sum_k a_k sin(k pi y) / (k pi)`` with ``sum |a_k| <= 0.6``, which is
monotone with ``w(0) = 0`` and ``w(1) = 1``.

White point
-----------
Finally every member is *clipped at a usable white point* (:func:`with_white_clip`).
Several of the forms above approach white asymptotically with zero slope: the film curves'
shoulders, ``log_logistic``, the filmic tone mappers, strong soft shoulders.  Normalised at
``E = 1`` they map the top few percent of brightness to a large part of the exposure range
(``f^-1(254/255)`` far below 1), which no camera delivers: its sensor, ADC or 8-bit encoder
*clips*, so the forward curve reaches 1 at the white point with a finite slope and stays
there.  The rule is stated in terms of the *relative slope* ``d log f / d log E = f'(E) /
(f(E) / E)`` (the local slope over the average slope from black; film's "point gamma"):
a member whose relative slope at ``E = 1`` is below ``MIN_WHITE_SLOPE = 0.08`` gets the
white point ``E_w`` = the largest exposure where it still reaches 0.08, and becomes
``f(E) = f(E_w E) / f(E_w)``: the encoding is used up to ``E_w`` and everything brighter
is clipped to 1 (``min(1, F(E) / F(x_white))`` over the original exposure axis).  Members
with a steeper end are unchanged (a gamma-3.2 power law has 0.31 everywhere, LogC3 used up
to reflectance 16 about 0.14 at white); a clipped member keeps its shape below its white
point (rescaled to the new white): only asymptotic tails are cut, in about a quarter of the
members.  With the relative slope >= 0.08 near white,
``f^-1(254/255) >= exp(-ln(255/254) / 0.08) ≈ 0.95``.  0.08 is a deliberately low
bound; over 3000 members the 5th percentiles of ``f^-1(254/255)`` and ``f^-1(250/255)``
are 0.95 and 0.80.

No curve here is fitted to, or derived from, DoRF or EMoR data.  One aggregate figure did
inform a choice: the bound 0.08 was picked so that those two 5th percentiles are near the
DoRF database's (about 0.94 and 0.80); no individual DoRF curve was looked at.

All randomness comes from a seeded :class:`numpy.random.Generator`, so the same seed gives
the same curves.  Its modules:

* :mod:`selfcal.response.curve_family.curve` -- the curve object, a normalised forward ``f``;
* :mod:`selfcal.response.curve_family.encodings` -- display encodings and camera log curves;
* :mod:`selfcal.response.curve_family.film_tone` -- film, filmic tone mappers, camera curves;
* :mod:`selfcal.response.curve_family.modifiers` -- monotone polynomials, mixtures, the
  modifiers and the white clip;
* :mod:`selfcal.response.curve_family.sampling` -- drawing members at random, sampling and
  inverting them.
"""

from __future__ import annotations

from .curve import ResponseCurve
from .encodings import (LOG_ENCODINGS, bt1886_inverse_eotf, gamma_curve, log_encoding,
                        rec709_oetf, srgb_encode, srgb_oetf)
from .film_tone import (aces_fitted, camera_tone_curve, hable, hd_negative, hd_reversal,
                        log_logistic, reinhard)
from .modifiers import (MIN_WHITE_SLOPE, bernstein_monotone, mixture, with_black_crush,
                        with_black_offset, with_linear_toe, with_power, with_soft_shoulder,
                        with_warp, with_white_clip)
from .sampling import (FAMILY_WEIGHTS, evaluate_curves, generate_inverse_curves,
                       generate_response_curves, invert_curve, modify_randomly,
                       sample_response_curves)

__all__ = [
    "ResponseCurve",
    "FAMILY_WEIGHTS",
    "gamma_curve",
    "srgb_encode",
    "srgb_oetf",
    "rec709_oetf",
    "bt1886_inverse_eotf",
    "log_encoding",
    "LOG_ENCODINGS",
    "hd_negative",
    "hd_reversal",
    "log_logistic",
    "reinhard",
    "hable",
    "aces_fitted",
    "camera_tone_curve",
    "bernstein_monotone",
    "mixture",
    "with_linear_toe",
    "with_black_offset",
    "with_black_crush",
    "with_soft_shoulder",
    "with_power",
    "with_warp",
    "with_white_clip",
    "MIN_WHITE_SLOPE",
    "sample_response_curves",
    "modify_randomly",
    "evaluate_curves",
    "invert_curve",
    "generate_response_curves",
    "generate_inverse_curves",
]
