"""Noise streams and raw exposures drawn here, independently of the package's simulator.

Streams are drawn by Fourier synthesis on a grid ``pad`` times longer than the
stream, of which the first part is kept: an exact draw of the stationary
Gaussian process whose one-sided spectrum is ``alpha + beta/f + gamma/f^exponent``
on that fine grid, with no periodic wrap-around of the kept part.
"""

import numpy as np

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule

FS = 1e5


def synth(n, coeffs, rng, nstreams=1, pad=8, fs=FS, exponent=1.3):
    a, b, g = coeffs
    length = pad * n
    f = np.fft.rfftfreq(length, 1 / fs)
    p = np.zeros_like(f)
    p[1:-1] = a + b / f[1:-1] + g / f[1:-1] ** exponent
    amp = np.sqrt(p * fs * length / 4)
    z = rng.normal(size=(nstreams, f.size)) + 1j * rng.normal(size=(nstreams, f.size))
    return np.fft.irfft(amp * z, length, axis=-1)[:, :n]


# -- raw exposures built here: every sample placed at its schedule time ----------------
PIXELS = (2.0071e-3, 8.4e-3, 0.1)  # Video8 + ROIC: what reference pixels see


PHANTOM = (3.71e-5, 8.4e-3, 0.0)  # Video8: what phantom reads see


def raw_exposure(seed, nframes=12, pixels=PIXELS, acn=False):
    """Raw ramps whose every sample is drawn at its schedule time.

    With ``acn`` the even and odd columns of each channel get independent
    realisations of the pixel noise (alternating column noise).
    """
    g = DetectorGeometry(512, 64, 4, ref_border=4)
    s = ReadoutSchedule(g, skip=24, ref_reads=32, phantom_reads=4, nframes=nframes,
                        frame_overhead=40)
    rng = np.random.default_rng(seed)
    total = s.nframes * s.frame_samples
    nreal = 2 * g.nchannels if acn else g.nchannels
    xp = synth(total, pixels, rng, nstreams=nreal, pad=4)
    xf = synth(total, PHANTOM, rng, nstreams=g.nchannels, pad=4)
    frames = np.arange(s.nframes)[:, None, None] * s.frame_samples
    samples = frames + s.pixel_samples()[None]
    stream = g.channel_of_column()
    if acn:
        stream = 2 * stream + np.arange(g.ncols) % 2
    data = xp[stream[None, None, :], samples]
    data = data + 1000.0 + 7.0 * np.arange(s.nframes)[:, None, None]  # offset + dark ramp
    psamp = frames + s.phantom_samples()[None]
    phantom = np.stack([xf[c][psamp].mean(axis=-1) for c in range(g.nchannels)], axis=-1)
    phantom = phantom + 3.0 * np.arange(s.nframes)[:, None, None]  # leakage drift
    return Exposure.from_arrays(data.astype(np.float32), s, phantom=phantom.astype(np.float32))
