r"""Response-function bases: the built-in log-domain PCA basis, and loading a basis file.

The JPEG-only path represents each channel's inverse response in the log domain,

.. math::  g(I) = \log f^{-1}(I) = g_0(I) + \sum_{n=1}^{N} h_n(I)\, c_n        \qquad (7)

(Lin, Kim, Süsstrunk & Brown, *Revisiting Radiometric Calibration for Color Computer
Vision*, ICCV 2011, §5, Eq. 7, after Grossberg & Nayar's empirical model of response,
EMoR, PAMI 2004), so that the exposure equation ``g(I') - g(I) = K'`` (Eq. 8) is linear in
the coefficients ``c_n``.  :class:`ResponseBasis` holds ``g0`` and the ``h_n`` sampled on a
grid of normalised intensities (K = 1024 points on [0, 1], like DoRF) and gives the solver
the design matrix (:meth:`ResponseBasis.design`).

Domains
-------
``domain="log"``
    ``mean`` and ``components`` describe ``g = log f^-1`` (Eq. 7).  The built-in basis.
``domain="linear"``
    They describe ``f^-1`` itself, as Grossberg & Nayar's inverse EMoR file (invemor.txt)
    does; read one with :func:`read_invemor`.

Normalisation
-------------
All curves are normalised so that ``f^-1(1) = 1``: in the log domain every training curve
has ``g(1) = 0``, so the mean and every component are exactly 0 at ``I = 1`` and *any*
coefficients give ``f^-1(1) = 1``.  Eq. 8 then fixes the remaining exposure scale.

The dark end
------------
``log f^-1(I) -> -inf`` as ``I -> 0``, and for a gamma-like curve ``log f^-1`` spans more
than ten natural-log units over the darkest few codes; left alone, this region (where
8-bit data are noise and quantisation anyway) would dominate a log-domain PCA.  The
built-in basis handles it in two deliberate ways:

1. **Floor.**  ``f^-1`` is floored at ``log_floor`` (ε, a linear value; 1e-5 for the
   built-in basis, 16.6 stops below white and below the first 8-bit code of sRGB or of
   any gamma up to 2.1) before the log, ``g = log max(f^-1, ε)``.
   At ``I = 0`` every training curve has ``g = log ε``, so ``g0(0) = log ε`` and every
   component is 0 there; the model's ``f^-1(0)`` is ε instead of 0 (a linear error of at
   most ε, far below one 8-bit code of any response).  Solvers of Eq. 8 should ignore
   samples whose ``f^-1`` could fall below ε (clipped/near-black codes), where the
   floored log no longer obeys Eq. 8.
2. **Weights.**  A log-domain error δg at intensity ``I`` is a linear error
   ``≈ f^-1(I) δg``.  The PCA is therefore *weighted* per intensity by
   ``w(I) = (rms_j f^-1_j(I) + κ)^2`` (κ a small constant that keeps some weight in the
   log domain everywhere; 0.05 for the built-in basis, so that below about 5 % of white,
   where 8-bit codes are coarse, errors count evenly in the log domain): the
   components are the principal axes of
   ``sqrt(w) (g - g0)`` mapped back by ``1/sqrt(w)``.  This orders components by the
   linear-domain variance they explain, which is what linearising an image needs, while
   the model stays log-domain for Eq. 8.  The weights are stored with the basis.

Fitting a given inverse curve (:meth:`ResponseBasis.fit_inverse_response`) minimises the
*linear-domain* error of ``f^-1`` (weighted log least squares as a start, then
Levenberg–Marquardt on ``exp(g0 + H c) - f^-1``).

The readers of Grossberg & Nayar's EMoR and DoRF files are in
:mod:`selfcal.response.basis_files` (importable from here too); :func:`read_invemor`, which
makes a :class:`ResponseBasis` of the inverse EMoR file, is here.
"""

from __future__ import annotations

import functools
import io as _io
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, ModelFileError
from . import basis_files as _files
from .basis_files import check_intensity, emor_blocks

__all__ = [
    "ResponseBasis",
    "log_pca_basis",
    "builtin_basis",
    "load_basis_file",
    "read_invemor",
    "BASIS_FORMAT_VERSION",
]

BASIS_FORMAT_VERSION = 1
_DOMAINS = ("log", "linear")


def _as_readonly(a, dtype=np.float64) -> np.ndarray:
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a


def _interp_weights(grid: np.ndarray, x: np.ndarray):
    """Left indices and fractions for linear interpolation of ``x`` on an increasing grid."""
    idx = np.searchsorted(grid, x, side="right") - 1
    idx = np.clip(idx, 0, grid.size - 2)
    t = (x - grid[idx]) / (grid[idx + 1] - grid[idx])
    return idx, t


# --------------------------------------------------------------------------------------
# the basis
# --------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ResponseBasis:
    """Mean and principal components of inverse responses on a grid (Lin et al. 2011, Eq. 7).

    Attributes
    ----------
    intensity : ndarray, shape (K,)
        Increasing grid of normalised intensities on [0, 1] (K = 1024, like DoRF/EMoR).
    mean : ndarray, shape (K,)
        ``g0`` on the grid: mean ``log f^-1`` (``domain="log"``) or mean ``f^-1``
        (``domain="linear"``).
    components : ndarray, shape (N_max, K)
        ``h_1 .. h_N_max`` on the grid, most important first.
    domain : {"log", "linear"}
        What ``mean`` and ``components`` describe (see the module docstring).
    name : str
        A short name ("selfcal built-in", "inverse EMoR", ...).
    log_floor : float
        ε, the linear floor applied before the log when the basis was built
        (``g = log max(f^-1, ε)``); 0 for a linear-domain basis.
    weights : ndarray, shape (K,), optional
        Per-intensity PCA weights the basis was built with (informative).
    explained_variance : ndarray, shape (N_max,), optional
        (Weighted) variance of the training set along each component.
    description : str
        Free text: how the basis was made.
    """

    intensity: np.ndarray
    mean: np.ndarray
    components: np.ndarray
    domain: str = "log"
    name: str = ""
    log_floor: float = 0.0
    weights: np.ndarray | None = None
    explained_variance: np.ndarray | None = None
    description: str = field(default="")

    def __post_init__(self):
        grid = _as_readonly(self.intensity)
        mean = _as_readonly(self.mean)
        comps = _as_readonly(self.components)
        if comps.ndim == 1:
            comps = _as_readonly(comps[None, :])
        if grid.ndim != 1 or grid.size < 2:
            raise InputError("basis intensity grid must be 1-D with at least 2 points")
        if np.any(np.diff(grid) <= 0) or grid[0] < 0 or grid[-1] > 1:
            raise InputError("basis intensity grid must increase within [0, 1]")
        if mean.shape != grid.shape or comps.ndim != 2 or comps.shape[1] != grid.size:
            raise InputError(f"basis shapes disagree: grid {grid.shape}, mean {mean.shape}, "
                             f"components {comps.shape}")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(comps))):
            raise InputError("basis mean and components must be finite")
        if self.domain not in _DOMAINS:
            raise InputError(f"basis domain must be one of {_DOMAINS}, not {self.domain!r}")
        if not (np.isfinite(self.log_floor) and self.log_floor >= 0):
            raise InputError("log_floor must be a non-negative number")
        object.__setattr__(self, "intensity", grid)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "components", comps)
        object.__setattr__(self, "log_floor", float(self.log_floor))
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "description", str(self.description))
        for key in ("weights", "explained_variance"):
            v = getattr(self, key)
            if v is not None:
                object.__setattr__(self, key, _as_readonly(v))

    # -- basics -------------------------------------------------------------------------

    @property
    def n_components(self) -> int:
        """Number of components available (``N_max``)."""
        return int(self.components.shape[0])

    def _n(self, n) -> int:
        if n is None:
            return self.n_components
        n = int(n)
        if not 0 <= n <= self.n_components:
            raise InputError(f"asked for {n} components; the basis {self.name!r} has "
                             f"{self.n_components}")
        return n

    def truncate(self, n: int) -> "ResponseBasis":
        """A copy keeping only the first ``n`` components."""
        n = self._n(n)
        ev = None if self.explained_variance is None else self.explained_variance[:n]
        return ResponseBasis(self.intensity, self.mean, self.components[:n], self.domain,
                             self.name, self.log_floor, self.weights, ev, self.description)

    def __repr__(self) -> str:
        return (f"ResponseBasis(name={self.name!r}, domain={self.domain!r}, "
                f"K={self.intensity.size}, n_components={self.n_components}, "
                f"log_floor={self.log_floor:g})")

    # -- evaluation ---------------------------------------------------------------------

    def design(self, intensity, n: int | None = None):
        """Mean and first ``n`` components at arbitrary intensities (linear interpolation).

        This is the linear model of Lin et al. 2011, Eq. 7, ``g(I) = g0(I) + H(I) c``; the
        Eq. 8 solver builds its system ``[H(I') - H(I)] c - K' = g0(I) - g0(I')`` from it.

        Parameters
        ----------
        intensity : array_like
            Normalised intensities in [0, 1] (any shape; flattened).
        n : int, optional
            Number of components (default all).

        Returns
        -------
        g0 : ndarray, shape (M,)
            The mean at each intensity.
        H : ndarray, shape (M, n)
            ``H[m, j] = h_{j+1}(intensity[m])``.
        """
        n = self._n(n)
        x = check_intensity(intensity)
        idx, t = _interp_weights(self.intensity, x)
        g0 = self.mean[idx] * (1.0 - t) + self.mean[idx + 1] * t
        c = self.components[:n]
        h = c[:, idx].T * (1.0 - t)[:, None] + c[:, idx + 1].T * t[:, None]
        return g0, h

    def model_values(self, coeffs, intensity=None) -> np.ndarray:
        """``g0 + sum_n c_n h_n``: ``log f^-1`` (log domain) or ``f^-1`` (linear domain)."""
        c = np.asarray(coeffs, dtype=np.float64).reshape(-1)
        n = self._n(c.size)
        if intensity is None:
            return self.mean + c @ self.components[:n]
        g0, h = self.design(intensity, n)
        return g0 + h @ c

    def inverse_response(self, coeffs, intensity=None) -> np.ndarray:
        """The inverse response ``f^-1`` for coefficients ``c`` (Lin et al. 2011, Eq. 7).

        Parameters
        ----------
        coeffs : array_like, shape (n,)
            Coefficients of the first ``n`` components (``n`` may be 0).
        intensity : array_like, optional
            Where to evaluate (values in [0, 1]); default the basis grid.

        Returns
        -------
        ndarray
            ``exp(g0 + H c)`` for a log-domain basis, ``g0 + H c`` for a linear one.
            For the log domain, ``f^-1(1) = 1`` exactly and ``f^-1(0) = log_floor``.
        """
        v = self.model_values(coeffs, intensity)
        if self.domain == "log":
            return np.exp(np.minimum(v, 50.0))
        return v

    def channel_inverses(self, coefficients, n: int) -> np.ndarray:
        """f⁻¹ of a log-domain basis on its grid for each channel's Eq. 7 coefficients,
        made non-decreasing (ours: a fit's f⁻¹ as the calibration keeps it; ``f⁻¹(1) = 1``
        is built into the basis).

        Parameters
        ----------
        coefficients : array_like, shape (3, >= n)
        n : int
            The components used.

        Returns
        -------
        ndarray, shape (grid size, 3)
        """
        g = self.mean[None, :] + np.asarray(coefficients)[:, :n] @ self.components[:n]
        return np.maximum.accumulate(np.exp(g).T, axis=0)

    def to_log_domain(self, log_floor: float = 1e-5) -> "ResponseBasis":
        """A log-domain basis (Eq. 7) from a linear-domain one, by linearising at the mean.

        ``log(g0 + H c) ≈ log g0 + (H / g0) c`` (first order in ``c``): the mean becomes
        ``log max(g0, ε)`` and each component ``h_n / max(g0, ε)``.  Exact at ``c = 0``;
        the span is the tangent space of the linear model at its mean, which is what the
        Eq. 8 solver needs (e.g. Grossberg & Nayar's inverse EMoR read by
        :func:`read_invemor`).  ``f^-1(1) = 1`` is kept when the linear basis has it.

        Parameters
        ----------
        log_floor : float
            ε > 0, the floor before the log (see the module docstring).

        Returns
        -------
        ResponseBasis
            ``self`` when already in the log domain.
        """
        if self.domain == "log":
            return self
        if not log_floor > 0:
            raise InputError("log_floor must be positive")
        g0 = np.maximum(self.mean, log_floor)
        comps = self.components / g0
        comps[:, self.mean <= log_floor] = 0.0
        return ResponseBasis(self.intensity, np.log(g0), comps, "log",
                             f"{self.name} (log, linearised at the mean)", log_floor,
                             description=(self.description + "; " if self.description else "")
                             + "converted to the log domain by first-order linearisation")

    # -- fitting ------------------------------------------------------------------------

    def fit_inverse_response(self, intensity, inverse_response, n: int, *,
                             refine: bool = True) -> np.ndarray:
        """Coefficients of the first ``n`` components that best match a given ``f^-1``.

        Minimises the linear-domain squared error ``sum_m (f^-1_model(I_m) - f^-1(I_m))^2``
        (the RMSE on [0, 1] when the samples are evenly spread).  Linear domain: one linear
        least-squares solve.  Log domain (Eq. 7): weighted log-domain least squares with
        weights ``max(f^-1, ε)`` (a log error δg costs ``f^-1 δg`` in linear terms) as the
        start, then Levenberg–Marquardt on ``exp(g0 + H c) - f^-1``.

        Parameters
        ----------
        intensity : array_like, shape (M,)
            Normalised intensities in [0, 1].
        inverse_response : array_like, shape (M,)
            The target ``f^-1`` at those intensities (normalised: ``f^-1(1) = 1``).
        n : int
            Number of components to use.
        refine : bool
            Run the non-linear refinement (log domain only).

        Returns
        -------
        ndarray, shape (n,)
        """
        n = self._n(n)
        x = check_intensity(intensity)
        t = np.asarray(inverse_response, dtype=np.float64).reshape(-1)
        if t.shape != x.shape:
            raise InputError(f"{t.size} inverse-response values for {x.size} intensities")
        if not np.all(np.isfinite(t)):
            raise InputError("inverse-response values must be finite")
        if n == 0:
            return np.zeros(0)
        g0, h = self.design(x, n)
        if self.domain == "linear":
            return np.linalg.lstsq(h, t - g0, rcond=None)[0]
        eps = max(self.log_floor, 1e-12)
        tf = np.maximum(t, eps)
        w = tf
        c0 = np.linalg.lstsq(h * w[:, None], w * (np.log(tf) - g0), rcond=None)[0]
        if not refine:
            return c0
        from scipy.optimize import least_squares

        def resid(c):
            return np.exp(np.minimum(g0 + h @ c, 50.0)) - t

        def jac(c):
            return np.exp(np.minimum(g0 + h @ c, 50.0))[:, None] * h

        method = "lm" if x.size >= n else "trf"
        res = least_squares(resid, c0, jac=jac, method=method, xtol=1e-12, ftol=1e-12,
                            gtol=1e-12, max_nfev=200 * (n + 1))
        c = res.x
        # keep the better of start and refinement (LM never worsens, but be safe)
        if np.sum(resid(c) ** 2) > np.sum(resid(c0) ** 2):
            c = c0
        return c

    # -- files --------------------------------------------------------------------------

    def _arrays(self) -> dict[str, np.ndarray]:
        d = {
            "format_version": np.array(BASIS_FORMAT_VERSION, dtype=np.int64),
            "intensity": self.intensity,
            "mean": self.mean,
            "components": self.components,
            "domain": np.array(self.domain),
            "name": np.array(self.name),
            "log_floor": np.array(self.log_floor, dtype=np.float64),
            "description": np.array(self.description),
        }
        if self.weights is not None:
            d["weights"] = self.weights
        if self.explained_variance is not None:
            d["explained_variance"] = self.explained_variance
        return d

    def to_bytes(self) -> bytes:
        """The .npz file content, byte-for-byte reproducible (fixed zip timestamps)."""
        buf = _io.BytesIO()
        with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for key, arr in self._arrays().items():
                member = _io.BytesIO()
                np.lib.format.write_array(member, np.asarray(arr, order="C"), allow_pickle=False)
                info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, member.getvalue(), compresslevel=9)
        return buf.getvalue()

    def save(self, path, *, force: bool = False):
        """Write the basis as a .npz file, atomically.

        Parameters
        ----------
        path : str or os.PathLike
            Output file (``.npz``).
        force : bool
            Allow replacing an existing file.

        Returns
        -------
        pathlib.Path
        """
        from ..io.images import write_bytes_atomic

        return write_bytes_atomic(path, self.to_bytes(), force=force)

    @classmethod
    def load(cls, path) -> "ResponseBasis":
        """Read a basis written by :meth:`save`.

        Raises
        ------
        ModelFileError
            When the file is missing, not a .npz, or lacks the basis arrays.
        """
        try:
            with open(path, "rb") as fh:
                return cls._from_npz(fh, path)
        except OSError as exc:
            raise ModelFileError(f"cannot read response basis ({exc.strerror or exc})", path) from None

    @classmethod
    def _from_npz(cls, fh, path) -> "ResponseBasis":
        try:
            with np.load(fh, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
            raise ModelFileError(f"not a response-basis .npz file ({exc})", path) from None
        missing = {"intensity", "mean", "components", "domain"} - set(d)
        if missing:
            raise ModelFileError(f"response-basis file lacks {sorted(missing)}", path)
        def scalar(key, default, kind):
            v = d.get(key)
            if v is None:
                return default
            v = np.asarray(v)
            if v.size != 1:
                raise ModelFileError(f"response-basis entry {key!r} must be a single value", path)
            return kind(v.reshape(-1)[0])

        version = scalar("format_version", 1, int)
        if version > BASIS_FORMAT_VERSION:
            raise ModelFileError(f"response-basis format {version} is newer than this selfcal "
                                 f"reads ({BASIS_FORMAT_VERSION})", path)
        try:
            return cls(
                intensity=d["intensity"], mean=d["mean"], components=d["components"],
                domain=scalar("domain", "log", str), name=scalar("name", "", str),
                log_floor=scalar("log_floor", 0.0, float),
                weights=d.get("weights"), explained_variance=d.get("explained_variance"),
                description=scalar("description", "", str),
            )
        except InputError as exc:
            raise ModelFileError(exc.reason, path) from None


# --------------------------------------------------------------------------------------
# building a log-domain PCA basis
# --------------------------------------------------------------------------------------

def log_pca_basis(intensity, inverse_curves, n_components: int = 25, *,
                  log_floor: float = 1e-5, weight_offset: float = 0.05,
                  name: str = "", description: str = "") -> ResponseBasis:
    """Weighted log-domain PCA of inverse responses (the model of Lin et al. 2011, Eq. 7).

    ``g_j = log max(f^-1_j, ε)``; ``g0`` is their mean; the components are the principal
    axes of ``sqrt(w) (g_j - g0)`` divided by ``sqrt(w)``, with per-intensity weights
    ``w(I) = (rms_j f^-1_j(I) + κ)^2`` (see the module docstring, *The dark end*).
    Components are ``w``-orthonormal, exactly 0 where all curves agree (``I = 0`` and
    ``I = 1``), and signed so that their largest weighted value is positive.

    Parameters
    ----------
    intensity : array_like, shape (K,)
        Increasing grid on [0, 1].
    inverse_curves : array_like, shape (J, K)
        ``f^-1`` of J curves on the grid, normalised to ``f^-1(1) = 1``.
    n_components : int
        Components to keep.
    log_floor : float
        ε > 0, the floor applied before the log.
    weight_offset : float
        κ >= 0 in the weights.
    name, description : str
        Stored with the basis.

    Returns
    -------
    ResponseBasis
        ``domain="log"``.
    """
    grid = np.asarray(intensity, dtype=np.float64)
    f = np.asarray(inverse_curves, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != grid.size:
        raise InputError(f"inverse curves must be (J, {grid.size}); got {f.shape}")
    if not log_floor > 0:
        raise InputError("log_floor must be positive")
    if not np.all(np.isfinite(f)):
        raise InputError("inverse curves must be finite")
    if f.shape[0] < 2:
        raise InputError("need at least two curves for a PCA")
    n_components = int(min(n_components, f.shape[0] - 1, grid.size))
    g = np.log(np.maximum(f, log_floor))
    g0 = g.mean(axis=0)
    x = g - g0
    s = np.sqrt(np.mean(f ** 2, axis=0)) + weight_offset
    _, sv, vt = np.linalg.svd(x * s, full_matrices=False)
    vt = vt[:n_components]
    big = np.argmax(np.abs(vt), axis=1)
    vt = vt * np.sign(vt[np.arange(vt.shape[0]), big])[:, None]
    comps = np.divide(vt, s, out=np.zeros_like(vt), where=s > 0)
    # where all curves agree (I = 0 at the floor, I = 1 at 0) the components are exactly 0
    agree = np.ptp(g, axis=0) == 0
    comps[:, agree] = 0.0
    g0 = np.where(agree, g[0], g0)
    return ResponseBasis(grid, g0, comps, "log", name, log_floor, s ** 2,
                         sv[:n_components] ** 2 / f.shape[0], description)


# --------------------------------------------------------------------------------------
# the built-in basis, and basis files
# --------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def builtin_basis() -> ResponseBasis:
    """The log-domain PCA basis shipped with selfcal (``selfcal/data/response_basis.npz``).

    Built by ``scripts/make_response_basis.py`` from the curve family of
    :mod:`selfcal.response.curve_family` (no DoRF/EMoR data), as in Lin et al. 2011,
    Eq. 7.  Cached: the same object is returned on every call.

    Returns
    -------
    ResponseBasis
    """
    from importlib import resources

    res = resources.files("selfcal") / "data" / "response_basis.npz"
    try:
        with res.open("rb") as fh:
            return ResponseBasis._from_npz(fh, str(res))
    except OSError as exc:
        raise ModelFileError(f"built-in response basis missing ({exc}); reinstall selfcal or "
                             "run scripts/make_response_basis.py", str(res)) from None


def load_basis_file(path) -> ResponseBasis:
    """Load a response basis from a file: a selfcal ``.npz`` or Grossberg & Nayar's invemor.txt.

    Parameters
    ----------
    path : str or os.PathLike
        ``*.npz`` written by :meth:`ResponseBasis.save`, or an inverse-EMoR text file.

    Returns
    -------
    ResponseBasis
        As stored (a text file gives a linear-domain basis; see
        :meth:`ResponseBasis.to_log_domain`).

    Raises
    ------
    InputError
        Naming the file, when it is missing or is neither kind (a forward emor.txt is
        recognised and refused with a hint).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("no such response-basis file", p)
    with open(p, "rb") as fh:
        head = fh.read(4)
    if head == b"PK\x03\x04" or p.suffix.lower() == ".npz":
        return ResponseBasis.load(p)
    try:
        return read_invemor(p)
    except InputError:
        try:
            _files.read_emor(p)
        except InputError:
            raise InputError("neither a selfcal .npz basis nor an inverse-EMoR text file "
                             "(blocks 'B =', 'g0 =', 'hinv(n)=')", p) from None
        raise InputError("this is the forward EMoR basis (emor.txt); the JPEG path needs "
                         "the inverse basis (invemor.txt)", p) from None


def read_invemor(path) -> ResponseBasis:
    """Read Grossberg & Nayar's inverse EMoR basis (invemor.txt) as a linear-domain basis.

    Blocks ``B =`` (intensity grid), ``g0 =`` (mean inverse response) and ``hinv(1)=`` ..
    ``hinv(25)=``: ``f^-1(B) = g0(B) + sum_n c_n hinv_n(B)``.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    ResponseBasis
        ``domain="linear"``, ``log_floor=0``.

    Raises
    ------
    InputError
        Naming the file, when it is missing, unreadable, or lacks a block.
    """
    grid, mean, comps = emor_blocks(path, "B", "g0", "hinv")
    if grid[0] < -1e-9 or grid[-1] > 1 + 1e-9:
        raise InputError("block 'B' must lie in [0, 1]", path)
    return ResponseBasis(np.clip(grid, 0.0, 1.0), mean, comps, "linear",
                         "inverse EMoR (Grossberg & Nayar)", 0.0,
                         description=f"read from {Path(path).name}")
