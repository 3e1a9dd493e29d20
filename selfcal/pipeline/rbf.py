"""RBF inverse colour mapping h⁻¹ ([Lin2011] §6).

[Lin2011] model the camera as ``i_c = f_c(h(T E))`` (Eq. 9) and undo the
colour (gamut) mapping ``h`` by scattered-data interpolation with radial basis functions
(Eq. 10)::

    h⁻¹(e) = Σ_i w_i ||e - e_i||  +  affine(e)

from control pairs ``e_i -> T E_i`` (linearised rendered colour -> colour-corrected raw;
"typically 1500 samples").  A raw is then ``E = T⁻¹ h⁻¹(f⁻¹(i))`` (Eq. 11).  The NUS
camera models store exactly this form (control points, weights and 4×3 affine rows).

The fit uses :class:`scipy.interpolate.RBFInterpolator` (``kernel="linear"``,
``degree=1``); its smoothing (a ridge on the kernel matrix; exact interpolation at 0) is
chosen by leave-one-out validation (Rippa's closed form, :func:`rbf_leave_one_out`), since
JPEG noise makes exact interpolation of 1,500 nearby points oscillate.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import numpy.typing as npt

from ..errors import CalibrationError, InputError

#: Number of control points ([Lin2011] §6: "typically 1500 samples are used").
N_CONTROL_POINTS = 1500
#: Smoothing values tried by the held-out selection.
SMOOTHING_GRID = (1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0)


class RBFColourMapping:
    """A fitted RBF colour mapping ``e -> Σ w_i ||e - c_i|| + affine(e)`` ([Lin2011] Eq. 10).

    Attributes
    ----------
    centres : numpy.ndarray
        ``(N, 3)`` control points ``e_i``.
    values : numpy.ndarray
        ``(N, 3)`` their targets (``T E_i``).
    smoothing : float
        The RBFInterpolator smoothing.
    validation : dict
        Leave-one-out RMSE per smoothing value tried (empty when not selected).
    """

    def __init__(self, centres: npt.ArrayLike, values: npt.ArrayLike, smoothing: float = 0.0,
                 validation: Mapping[float, float] | None = None) -> None:
        from scipy.interpolate import RBFInterpolator

        self.centres = np.ascontiguousarray(centres, dtype=np.float64)
        self.values = np.ascontiguousarray(values, dtype=np.float64)
        self.smoothing = float(smoothing)
        self.validation = dict(validation or {})
        if self.centres.ndim != 2 or self.centres.shape[1] != 3 or \
                self.values.shape != self.centres.shape:
            raise InputError("RBF control points and values must be two (N, 3) arrays")
        try:
            self._rbf = RBFInterpolator(self.centres, self.values, kernel="linear", degree=1,
                                        smoothing=self.smoothing)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise CalibrationError(f"the RBF colour mapping cannot be fitted ({exc}); the "
                                   "control points may be degenerate (e.g. all grey)") from None

    def __call__(self, e, chunk: int = 50_000) -> np.ndarray:
        """Evaluate at ``(..., 3)`` points (float64), in chunks to bound memory."""
        e = np.asarray(e, dtype=np.float64)
        flat = e.reshape(-1, 3)
        out = np.empty_like(flat)
        for s in range(0, flat.shape[0], chunk):
            out[s:s + chunk] = self._rbf(flat[s:s + chunk])
        return out.reshape(e.shape)

    def to_dict(self) -> dict:
        return {"kernel": "linear", "degree": 1, "smoothing": self.smoothing,
                "centres": self.centres.tolist(), "values": self.values.tolist(),
                "validation": {str(k): float(v) for k, v in self.validation.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "RBFColourMapping":
        return cls(d["centres"], d["values"], float(d["smoothing"]),
                   {float(k): v for k, v in d.get("validation", {}).items()})


def rbf_leave_one_out(centres, values, smoothing_grid=SMOOTHING_GRID,
                      error_transform=None, refine: bool = False, groups=None) -> dict:
    """Leave-one-out RMSE of the linear-kernel RBF (degree-1 affine part) per smoothing.

    Rippa's closed form ([Rippa1999]): for the system
    ``(K + s I) a + P b = y``, ``Pᵀ a = 0`` (``K_ij = -||c_i - c_j||`` as in
    :class:`scipy.interpolate.RBFInterpolator`), the error at ``c_i`` of the interpolant
    fitted without sample ``i`` is ``a_i / (A⁻¹)_ii``.  With ``Q`` an orthonormal basis of
    the null space of ``Pᵀ``, ``A⁻¹``'s kernel block is ``Q (QᵀKQ + s I)⁻¹ Qᵀ`` (positive
    definite: the linear kernel is conditionally positive definite), so each smoothing
    value costs one Cholesky factorisation and one triangular solve,
    ``X = L⁻¹ Qᵀ``: ``a = Xᵀ X y`` and ``(A⁻¹)_ii = ||X_:i||²``.

    With ``groups`` the error is leave-one-group-out, the block form of the same identity
    ([Dubrule1983]):
    the errors at the centres of group ``G`` with the interpolant fitted without them are
    ``((A⁻¹)_GG)⁻¹ a_G``, ``(A⁻¹)_GG = X_:Gᵀ X_:G``.

    Parameters
    ----------
    centres, values : numpy.ndarray
        ``(n, 3)`` control points and targets.
    smoothing_grid : sequence of float
    error_transform : callable, optional
        Applied to the ``(n, 3)`` held-out residuals before the RMSE (a linear map, e.g.
        ``M⁻¹`` for raw units).
    refine : bool
        Then also try half a decade either side of the best value (the kernel system
        ``QᵀKQ`` is formed once for all values).
    groups : array_like, optional
        ``(n,)`` labels: leave-one-group-out instead of leave-one-out.

    Returns
    -------
    dict
        smoothing -> held-out RMSE (values whose system is not positive definite are
        left out).
    """
    import scipy.linalg as sl
    from scipy.spatial.distance import cdist

    c = np.asarray(centres, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    n = c.shape[0]
    p = np.hstack([np.ones((n, 1)), c])
    q_full, _ = np.linalg.qr(p, mode="complete")
    q = q_full[:, 4:]
    b = q.T @ (-cdist(c, c)) @ q
    qt = np.ascontiguousarray(q.T)
    tf = (lambda r: r) if error_transform is None else error_transform
    labels = None
    if groups is not None:
        labels = np.asarray(groups).reshape(-1)
        if labels.shape[0] != n:
            raise InputError(f"groups has {labels.shape[0]} labels for {n} centres")
        if np.unique(labels).size < 2:
            labels = None           # one group: plain leave-one-out
    out = {}
    eye = np.eye(b.shape[0])

    def score(s):
        try:
            low = sl.cholesky(b + float(s) * eye, lower=True)
        except np.linalg.LinAlgError:
            return
        x = sl.solve_triangular(low, qt, lower=True)
        a = x.T @ (x @ y)
        if labels is None:
            diag = np.einsum("ij,ij->j", x, x)
            err = a / diag[:, None]
        else:
            err = np.empty_like(a)
            for g in np.unique(labels):
                rows = labels == g
                xg = x[:, rows]
                try:
                    err[rows] = np.linalg.solve(xg.T @ xg, a[rows])
                except np.linalg.LinAlgError:
                    return
        out[float(s)] = float(np.sqrt(np.mean(tf(err) ** 2)))

    for s in smoothing_grid:
        score(s)
    if refine and out:
        best = min(out, key=out.__getitem__)
        for s in (best / np.sqrt(10), best * np.sqrt(10)):
            score(s)
    return out


def rbf_inverse_colour_mapping(e: np.ndarray, target: np.ndarray, *,
                               n_centres: int = N_CONTROL_POINTS, smoothing: float | str = "auto",
                               smoothing_grid: Sequence[float] = SMOOTHING_GRID,
                               error_transform: Callable[[np.ndarray], np.ndarray] | None = None,
                               seed: int = 0,
                               groups: npt.ArrayLike | None = None) -> RBFColourMapping:
    """Fit the inverse colour mapping ``h⁻¹: e -> T E`` of [Lin2011], Eq. 10-11.

    ``h⁻¹(e) = Σ_i w_i ||e - e_i|| + affine(e)`` through the control pairs
    ``e_i -> T E_i`` (scipy's RBFInterpolator, ``kernel="linear"``, ``degree=1``).

    Parameters
    ----------
    e : array_like
        ``(n, 3)`` linearised rendered colours ``f⁻¹(i)``.
    target : array_like
        ``(n, 3)`` colour-corrected raws ``T E`` (here ``M ρ``).
    n_centres : int
        Control points used (a seeded random subset when ``n`` is larger; 1500 as in §6).
    smoothing : float or "auto"
        RBFInterpolator smoothing; ``"auto"`` picks the value of ``smoothing_grid`` (one
        per decade) with the lowest leave-one-out error (:func:`rbf_leave_one_out`, closed
        form), then tries half a decade either side of it.
    error_transform : callable, optional
        A linear map applied to held-out residuals (e.g. ``M⁻¹``, for raw units).
    seed : int
        Seeds the subset of control points.
    groups : array_like, optional
        ``(n,)`` labels (e.g. the scene of each sample): the smoothing is chosen by
        leave-one-group-out (:func:`rbf_leave_one_out`).

    Returns
    -------
    RBFColourMapping
        With the held-out scores in ``validation``.

    Raises
    ------
    CalibrationError
        Too few samples (fewer than 10), or a degenerate set of control points.
    """
    e = np.asarray(e, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 3 or target.shape != e.shape:
        raise InputError(f"RBF data must be two (n, 3) arrays, got {e.shape}, {target.shape}")
    labels = np.zeros(e.shape[0]) if groups is None else np.asarray(groups).reshape(-1)
    if labels.shape[0] != e.shape[0]:
        raise InputError(f"groups has {labels.shape[0]} labels for {e.shape[0]} samples")
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(target), axis=1)
    e, target, labels = e[ok], target[ok], labels[ok]
    # duplicate control points make the interpolation matrix singular: keep one of each
    _, first = np.unique(np.round(e, 9), axis=0, return_index=True)
    first = np.sort(first)
    e, target, labels = e[first], target[first], labels[first]
    if e.shape[0] < 10:
        raise CalibrationError(f"the RBF colour mapping needs at least 10 distinct samples, "
                               f"got {e.shape[0]}")
    if e.shape[0] > n_centres:
        pick = np.sort(np.random.default_rng(seed).choice(e.shape[0], n_centres,
                                                          replace=False))
        e, target, labels = e[pick], target[pick], labels[pick]
    if smoothing != "auto":
        return RBFColourMapping(e, target, float(smoothing))
    try:
        scores = rbf_leave_one_out(e, target, smoothing_grid, error_transform, refine=True,
                                   groups=None if groups is None else labels)
    except np.linalg.LinAlgError:
        scores = {}
    if not scores:
        raise CalibrationError("the RBF colour mapping cannot be fitted: the control points "
                               "are degenerate (e.g. on a plane)")
    best = min(scores, key=scores.__getitem__)
    return RBFColourMapping(e, target, best, validation=scores)
