"""Covariance of the values row reads give, and kriging weights for a channel's drift.

A row read of one channel gives, for a group of its columns, one value: the
mean of those pixels, minus the mean of the ``c`` phantom samples taken just
before the read once the phantom has been subtracted (paper §2.5).  Every read
has the same layout in time (`~spherex_reduce.ReadoutSchedule`: ``c`` phantom
samples, the pixels, the overhead), so the covariance of the values of two
reads depends only on how many reads apart they are: `ReadCovariance`
computes it from the noise model's structure functions, in the *frames* domain
(the stream itself, a generalised covariance ``-D/2``: only combinations whose
weights sum to zero have a finite variance) or the *slopes* domain (the
least-squares slope over the frames, the process of PSD ``p(f) |H(f)|^2``
that the direct slope synthesis draws).

`kriging_weights` turns it into the best linear unbiased estimate of each
read's value from some reads' values when every (frame, channel) adds an
unknown constant (a flat prior): universal kriging with a constant mean.  When
the noise is white, the weights are equal: the estimate is the mean.
"""

import numpy as np

from ..core.limits import check_size
from .structure_functions import cin, g_power, inv_f_structure, power_structure
from .variance import slope_frames

__all__ = ["DOMAINS", "KINDS", "Kriging", "ReadCovariance", "kriging_weights"]

#: ``frames``: the stream of each frame; ``slopes``: the ramp-fitted slope image.
DOMAINS = ("frames", "slopes")
#: Reads apart up to which the sum over a read's samples is exact (beyond: a quadrature rule).
_EXACT_READS = 3
#: Lags (samples) from which the structure functions take their asymptotic form, whose
#: smooth and alternating parts the rule integrates separately (``pi * lag >= 40``).
_ASYMPTOTIC = 16
#: Nodes of that rule (Chebyshev): exact for polynomials of degree < this in the offset.
_NODES = 16


#: What a read value is: its pixels' mean, that minus its phantom value, or the phantom value;
#: ``side`` and ``side-subtracted``: the mean over the channels that have side reference
#: columns of their side pixels' mean (minus each channel's phantom value).
KINDS = ("pixels", "subtracted", "phantom", "side", "side-subtracted")


def _functional(component, kind, pixel_offsets, phantom_reads, weights=None):
    """Sample offsets (within a read) and coefficients of one component's part of a value
    (``weights``: of each pixel offset; default equal)."""
    offs, coefs = [], []
    c = int(phantom_reads)
    if kind != "phantom" and component.seen_by_pixels:
        offs.append(np.asarray(pixel_offsets, dtype=np.int64))
        coefs.append(np.full(len(pixel_offsets), 1.0 / len(pixel_offsets))
                     if weights is None else np.asarray(weights, dtype=float))
    if kind not in ("pixels", "side") and c and component.seen_by_phantom:
        offs.append(np.arange(-c, 0, dtype=np.int64))
        coefs.append(np.full(c, (1.0 if kind == "phantom" else -1.0) / c))
    if not offs:
        return np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(offs), np.concatenate(coefs)


def _pair_distribution(component, a, b):
    """Signed weights ``h[d]`` with ``Cov(A at read i, B at read j) = sum_d h[d] K((j - i) R + d)``
    for one component, summed over its independent realisations (even and odd samples
    with ``acn``); ``a`` and ``b`` are `_functional` results."""
    (oa, wa), (ob, wb) = a, b
    if oa.size == 0 or ob.size == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    lo = int(ob.min() - oa.max())
    h = np.zeros(int(ob.max() - oa.min()) - lo + 1)
    for p in ((0, 1) if component.acn else (None,)):
        ka = np.ones(oa.size, bool) if p is None else oa % 2 == p
        kb = np.ones(ob.size, bool) if p is None else ob % 2 == p
        if ka.any() and kb.any():
            d = (ob[kb][None, :] - oa[ka][:, None]).ravel()
            np.add.at(h, d - lo, np.outer(wa[ka], wb[kb]).ravel())
    d = np.arange(lo, lo + h.size)
    nz = h != 0
    return d[nz], h[nz]


def _chebyshev_nodes(half, n=_NODES):
    """Chebyshev nodes on ``[-half, half]`` (symmetric: node ``n-1-i`` is minus node ``i``)."""
    return half * np.cos(np.pi * (np.arange(n) + 0.5) / n)


def _chebyshev_weights(d, h, half, n=_NODES):
    """Weights on `_chebyshev_nodes` reproducing ``sum_d h[d] q(d)`` for polynomials ``q``
    of degree < n."""
    nodes = _chebyshev_nodes(1.0, n)
    vander = np.polynomial.chebyshev.chebvander(nodes, n - 1).T  # (degree, node)
    moments = np.polynomial.chebyshev.chebvander(d / half, n - 1).T @ h
    return np.linalg.solve(vander, moments)


class ReadCovariance:
    """Covariance of read values ``m`` reads apart, for channel-scope and common noise.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
        Row time (samples per read), frame time, frames and pixel rate.
    components : sequence of `~spherex_reduce.noise.NoiseComponent`
    pixel_offsets : array_like of int
        Sample offsets, within a read, of the pixels the value averages (one
        channel's columns of a group; the same for every channel).
    domain : {'frames', 'slopes'}
    common : set of str
        Names of the components one stream of which all channels see.
    side_offsets : sequence of array_like of int
        Sample offsets of the side reference pixels of each channel that has
        them (the values of kinds ``side`` and ``side-subtracted`` average
        them per channel, then over those channels).

    Examples
    --------
    White noise only: values of different reads are uncorrelated.

    >>> from spherex_reduce import ReadoutSchedule
    >>> from spherex_reduce.noise import NoiseComponent
    >>> from spherex_reduce.noise.read_covariance import ReadCovariance
    >>> s = ReadoutSchedule(nframes=4)
    >>> rc = ReadCovariance(s, [NoiseComponent("w", alpha=2e-3)], range(64), "frames")
    >>> float(rc.white("pixels", 64, "channel")), rc.colored(range(3))["channel"].tolist()
    (1.5625, [0.0, 0.0, 0.0])
    """

    def __init__(self, schedule, components, pixel_offsets, domain, *, common=frozenset(),
                 side_offsets=()):
        if domain not in DOMAINS:
            raise ValueError(f"domain must be one of {DOMAINS}, got {domain!r}")
        self.schedule, self.domain = schedule, domain
        self.components = [c for c in components if not c.is_zero]
        self.pixel_offsets = np.asarray(pixel_offsets, dtype=np.int64)
        self.common = frozenset(common)
        self.side_offsets = [np.asarray(o, dtype=np.int64) for o in side_offsets]
        if any(o.size == 0 for o in self.side_offsets):
            raise ValueError("side_offsets: every channel's side columns need a pixel")
        fs = schedule.geometry.pixel_rate
        if domain == "slopes":
            w, a, shifts = slope_frames(schedule)
            self._frame_weights, self._frame_shifts = a, shifts
            scale = float(np.sum(w * w))
        else:
            self._frame_weights = self._frame_shifts = None
            scale = 1.0
        self._white = {"pixels": {"channel": 0.0, "common": 0.0},
                       "phantom": {"channel": 0.0, "common": 0.0}}
        for comp in self.components:
            v = comp.white_variance(fs) * scale
            if comp.seen_by_pixels:
                self._white["pixels"][self._scope(comp)] += v
            if schedule.phantom_reads and comp.seen_by_phantom:
                self._white["phantom"][self._scope(comp)] += v
        self._parts = {}
        self._far_tables = {}

    def white(self, kind, npixels, scope):
        """White variance of a value of ``kind`` averaging ``npixels`` pixels (array_like;
        a side value averages every side pixel: ``npixels`` gives only the shape)."""
        c = max(self.schedule.phantom_reads, 1)
        ph = self._white["phantom"][scope] / c
        if kind == "phantom":
            return np.full(np.shape(npixels), ph)
        if kind in ("side", "side-subtracted"):
            nout = len(self.side_offsets)
            if scope == "channel":  # the channels' samples are independent
                pix = self._white["pixels"][scope] * sum(1.0 / o.size for o in
                                                         self.side_offsets) / nout ** 2
                ph = ph / nout
            else:  # one common sample at each offset, whatever channel reads it
                _, w = self._side_functional()
                pix = self._white["pixels"][scope] * float(np.sum(w * w))
            pix = np.full(np.shape(npixels), pix)
            return pix if kind == "side" else pix + ph
        pix = self._white["pixels"][scope] / np.asarray(npixels, dtype=float)
        return pix if kind == "pixels" else pix + ph

    def _side_functional(self, channel=None):
        """Pixel offsets and weights of a side value (the mean over side channels of each
        one's side pixels' mean; its common part adds the weights of equal offsets), or,
        with ``channel``, of that channel's side pixels' mean."""
        if not self.side_offsets:
            raise ValueError("this covariance has no side columns (side_offsets)")
        if channel is not None:
            o = self.side_offsets[channel]
            return o, np.full(o.size, 1.0 / o.size)
        offs = np.concatenate(self.side_offsets)
        w = np.concatenate([np.full(o.size, 1.0 / (o.size * len(self.side_offsets)))
                            for o in self.side_offsets])
        uniq, inv = np.unique(offs, return_inverse=True)
        return uniq, np.bincount(inv, weights=w)

    def _value_functional(self, comp, kind, channel=None):
        """`_functional` of one component's part of a value of ``kind``."""
        c = self.schedule.phantom_reads
        if kind in ("side", "side-subtracted"):
            offsets, weights = self._side_functional(channel)
            return _functional(comp, kind, offsets, c, weights)
        return _functional(comp, kind, self.pixel_offsets, c)

    def _distribution(self, comp, scope, kind_a, kind_b):
        """`_pair_distribution` of two values; two side values' channel part is the mean over
        side channels of each one's own (``1 / nout`` of it: the channels are
        independent), not the pairs of different channels' samples."""
        sides = ("side", "side-subtracted")
        if not (scope == "channel" and kind_a in sides and kind_b in sides):
            return _pair_distribution(comp, self._value_functional(comp, kind_a),
                                      self._value_functional(comp, kind_b))
        nout = len(self.side_offsets)
        acc = {}
        for o in range(nout):
            d, h = _pair_distribution(comp, self._value_functional(comp, kind_a, o),
                                      self._value_functional(comp, kind_b, o))
            for di, hi in zip(d.tolist(), h.tolist(), strict=True):
                acc[di] = acc.get(di, 0.0) + hi / nout ** 2
        d = np.array(sorted(acc), dtype=np.int64)
        return d, np.array([acc[k] for k in d.tolist()])

    def _pairs(self, kind_a, kind_b):
        key = (kind_a, kind_b)
        if key not in self._parts:
            parts = []
            for comp in self.components:
                if not (comp.beta or comp.gamma):
                    continue
                d, h = self._distribution(comp, self._scope(comp), kind_a, kind_b)
                if d.size:
                    half = float(self.schedule.row_samples)  # offsets within a read differ
                    alt = np.where(d % 2 == 0, h, -h)        # by less than this
                    parts.append((comp, self._scope(comp), d, h,
                                  (_chebyshev_weights(d, h, half),
                                   _chebyshev_weights(d, alt, half))))
            self._parts[key] = parts
        return self._parts[key]

    def _scope(self, comp):
        return "common" if comp.name in self.common else "channel"

    def _shifts(self):
        """Frame weights ``a_j`` and shifts (samples: ``j F``, or differences of uneven read
        times) of the slopes domain (`~spherex_reduce.noise.variance.slope_frames`)."""
        return self._frame_weights, self._frame_shifts

    def _k(self, x, basis, parity=None):
        """The (generalised) covariance of the stream, or of its slopes, at lags ``x``.

        With ``parity`` (+1 or -1), the structure functions' asymptotic form with
        ``cos(pi lag)`` set to it (their values at integer lags of that parity,
        continued smoothly): for lags beyond `_ASYMPTOTIC` only.
        """
        fs = self.schedule.geometry.pixel_rate

        def d(lag, sign):
            lag = np.abs(lag)
            if sign is None:
                return inv_f_structure(lag) if basis == "beta" else power_structure(lag, fs, basis)
            z = np.pi * lag
            cos = np.full(lag.shape, float(sign))
            if basis == "beta":
                return 2 * cin(z, cos)
            z_e1 = z ** (basis - 1)
            return 2 * (2 / fs) ** (basis - 1) * z_e1 * g_power(z.ravel(), basis, cos.ravel(),
                                                                z_e1.ravel()).reshape(z.shape)

        if self._frame_weights is None:
            return -0.5 * d(x, parity)
        a, shifts = self._shifts()
        out = np.zeros(np.shape(x))
        for aj, sj in zip(a, shifts, strict=True):
            # (-1)^(x + jF) = (-1)^x (-1)^(jF): the parity of the shifted lag
            sign = None if parity is None else parity * (1 - 2 * (int(sj) % 2))
            out += aj * d(x + float(sj), sign)
        return -0.5 * out

    def _near(self, m):
        """Which reads-apart ``m`` need the exact sum: a read's samples reach lags (of any
        frame shift) where the structure functions are not yet asymptotic."""
        rs = self.schedule.row_samples
        near = np.abs(m) <= _EXACT_READS
        shifts = np.zeros(1, np.int64) if self._frame_weights is None else self._shifts()[1]
        closest = np.min(np.abs(np.abs(m)[:, None] * rs + shifts[None, :]), axis=1)
        return near | (closest < rs + _ASYMPTOTIC)

    def colored(self, reads_apart, kind_a="subtracted", kind_b=None):
        """Covariance of the correlated (``1/f``, power-law) terms of two read values.

        Parameters
        ----------
        reads_apart : array_like of int
            ``m``: the second read is ``m`` reads after the first (in one frame).
        kind_a, kind_b : str
            What the first and the second value are (`KINDS`; ``kind_b``
            defaults to ``kind_a``): the mean of the pixels, that minus the
            read's phantom value, the phantom value, or a side value (with or
            without the phantom values subtracted).

        Returns
        -------
        dict
            ``'channel'`` and ``'common'``: `numpy.ndarray` like ``reads_apart``.
        """
        kind_b = kind_a if kind_b is None else kind_b
        m = np.asarray(reads_apart, dtype=np.int64)
        out = {"channel": np.zeros(m.shape), "common": np.zeros(m.shape)}
        parts = self._pairs(kind_a, kind_b)
        if not parts or m.size == 0:
            return out
        rs = float(self.schedule.row_samples)
        uniq, inverse = np.unique(m, return_inverse=True)
        near = self._near(uniq)
        sign = np.where((uniq * self.schedule.row_samples) % 2 == 0, 1.0, -1.0)[~near]
        cache = {}
        for comp, scope, d, h, (smooth, alternating) in parts:
            value = np.zeros(uniq.size)
            for basis, coef in (("beta", comp.beta), (comp.exponent, comp.gamma)):
                if not coef:
                    continue
                key = (basis, d.tobytes(), h.tobytes())
                if key not in cache:
                    k = np.empty(uniq.size)
                    k[near] = self._k(uniq[near, None] * rs + d[None, :], basis) @ h
                    s_far, a_far = self._far(basis, uniq[~near])
                    k[~near] = s_far @ smooth + sign * (a_far @ alternating)
                    cache[key] = k
                value += coef * cache[key]
            out[scope] += value[inverse.reshape(m.shape)]
        return out

    def _far(self, basis, m):
        """The smooth and the alternating part of ``K(m R + node)`` at the Chebyshev nodes
        (at integer lags ``K = smooth + (-1)^lag alternating``), each ``(len(m), nodes)``:
        computed once per basis for ``m >= 0`` (``K`` is even and the nodes symmetric)."""
        rs = float(self.schedule.row_samples)
        tables = self._far_tables.get(basis)
        top = int(np.max(np.abs(m))) if m.size else 0
        if tables is None or tables[0].shape[0] <= top:
            reach = np.arange(max(top, self.schedule.n_reads) + 1)
            x = reach[:, None] * rs + _chebyshev_nodes(rs)[None, :]
            far = ~self._near(reach)
            plus, minus = np.zeros(x.shape), np.zeros(x.shape)
            plus[far] = self._k(x[far], basis, +1)
            minus[far] = self._k(x[far], basis, -1)
            tables = ((plus + minus) / 2, (plus - minus) / 2)
            self._far_tables[basis] = tables
        out = []
        for table in tables:
            t = table[np.abs(m)]
            neg = m < 0
            t[neg] = t[neg][:, ::-1]  # K(-|m| R + x) = K(|m| R - x)
            out.append(t)
        return out


class Kriging:
    """A solved kriging system whose observations may later get more white variance.

    Solves ``[[K, F], [F^T, 0]] [L; nu] = [k; f]`` once (`kriging_weights`
    describes the problem) and keeps ``A^-1`` applied to the first ``nupdate``
    observations' unit vectors, so that adding white variance ``e_i`` to
    some of them (fewer pixels averaged; ``inf``: the observation is dropped)
    is a Woodbury update of rank ``len(e)``, not a new solve.

    Parameters
    ----------
    c_oo, c_ot, c_tt, regularization, constants
        As `kriging_weights`.
    nupdate : int
        How many of the first observations `weights` may change.
    """

    def __init__(self, c_oo, c_ot, c_tt, regularization=0.0, constants=None, nupdate=0):
        c_oo = np.asarray(c_oo, dtype=np.float64)
        c_ot = np.asarray(c_ot, dtype=np.float64)
        n, ntargets = c_ot.shape
        groups = np.zeros(n, int) if constants is None else np.asarray(constants, int)
        q = int(groups.max()) + 1
        check_size(self.nbytes(n, ntargets, nupdate, q),
                   f"a kriging solve of {n} observations for {ntargets} targets")
        a = np.zeros((n + q, n + q))
        a[:n, :n] = c_oo
        if regularization:
            a[np.arange(n), np.arange(n)] += regularization * np.mean(np.abs(np.diag(c_oo)))
        a[np.arange(n), n + groups] = a[n + groups, np.arange(n)] = 1.0
        rhs = np.zeros((n + q, ntargets + nupdate))
        rhs[:n, :ntargets] = c_ot
        rhs[n, :ntargets] = 1.0
        rhs[np.arange(nupdate), ntargets + np.arange(nupdate)] = 1.0
        sol = np.linalg.solve(a, rhs)  # LU: several times faster than scipy's "sym" here
        self.n = n
        self.x, self.z = sol[:, :ntargets], sol[:, ntargets:]
        # [K F; F^T 0][L; nu] = [k; f]  =>  L^T K L = L^T k - f^T nu, so the error variance
        # is c_tt - sum L k - nu_0; an update's change needs only z^T k (nupdate x T)
        self.variance = (np.asarray(c_tt, dtype=np.float64)
                         - np.sum(self.x[:n] * c_ot, axis=0) - self.x[n])
        self._zk = self.z[:n].T @ c_ot

    @staticmethod
    def nbytes(nobs, ntargets, nupdate=0, nconstants=1):
        """Bytes a `Kriging` of ``nobs`` observations and ``ntargets`` targets allocates at
        its peak: the bordered system and its right-hand sides, the copies
        `numpy.linalg.solve` factorises, and the solution it keeps.

        Examples
        --------
        >>> from spherex_reduce.noise.read_covariance import Kriging
        >>> Kriging.nbytes(2104, 2072, 32, 2) / 1e6  # the paper's case with phantom values
        177.3...
        """
        size = float(nobs) + nconstants
        return 8.0 * (2 * size * size + 3 * size * (float(ntargets) + nupdate))

    def weights(self, extra=None):
        """Weights ``(T, n)`` and predicted error variances ``(T,)``.

        Parameters
        ----------
        extra : array_like, shape (nupdate,), optional
            White variance added to each of the first observations (0: none,
            ``inf``: the observation is not used).
        """
        x, var = self.x, self.variance
        if extra is not None:
            extra = np.asarray(extra, dtype=float)
            m = np.flatnonzero(extra != 0)
            if m.size:
                with np.errstate(divide="ignore"):
                    inv = np.where(np.isinf(extra[m]), 0.0, 1.0 / extra[m])
                s = np.diag(inv) + self.z[m][:, m]
                y = np.linalg.solve(s, x[m])
                x = x - self.z[:, m] @ y
                var = var + np.sum(y * self._zk[m], axis=0) + self.z[self.n, m] @ y
        return x[:self.n].T, var


def kriging_weights(c_oo, c_ot, c_tt, regularization=0.0, constants=None):
    """Best linear unbiased weights under unknown constants (universal kriging).

    Estimates targets ``t_k`` from observations ``o_i`` as ``sum_i L[k, i] o_i``
    with the smallest error variance, such that unknown constants added to the
    observations cancel: the weights of the observations of constant 0 (which
    the targets share) sum to 1, those of every other constant to 0.

    Parameters
    ----------
    c_oo : `numpy.ndarray`, shape (n, n)
        (Generalised) covariance of the observations.
    c_ot : `numpy.ndarray`, shape (n, T)
        Between observations and targets.
    c_tt : `numpy.ndarray`, shape (T,)
        Of each target with itself.
    regularization : float
        Added to the diagonal of ``c_oo``, relative to its mean diagonal.
    constants : array_like of int, shape (n,), optional
        Which unknown constant each observation has (0, 1, ...); default all 0.

    Returns
    -------
    weights : `numpy.ndarray`, shape (T, n)
    variance : `numpy.ndarray`, shape (T,)
        The predicted error variance of each estimate (``E[(t̂ - t)^2]``).

    Examples
    --------
    Uncorrelated, equal observations: every weight is ``1/n`` (the mean).

    >>> import numpy as np
    >>> from spherex_reduce.noise.read_covariance import kriging_weights
    >>> w, v = kriging_weights(np.eye(4), np.zeros((4, 2)), np.full(2, 1.0))
    >>> w.tolist(), v.tolist()
    ([[0.25, 0.25, 0.25, 0.25], [0.25, 0.25, 0.25, 0.25]], [1.25, 1.25])
    """
    return Kriging(c_oo, c_ot, c_tt, regularization, constants).weights()
