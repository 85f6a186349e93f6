"""Raw darks drawn sample by sample here, independently of the package's simulator.

Every noise component is a stream drawn at the pixel rate over the whole
exposure (`_noise_streams.synth`: Fourier synthesis on a padded grid, no
wrap-around); a pixel's value is its stream at the sample the schedule reads
it, a phantom value the mean of the streams at its ``c`` samples.  Components
with ``acn`` have one stream per channel and column parity (a phantom sample
``i`` has the parity ``(i - c) % 2``, as in the simulator); ``common`` ones one
stream for all channels; ``visibility`` says whether pixels, phantom or both
see it, both seeing the same samples of the same stream (the simulator drops
that coherence above ``f_B / 2``: see ``spherex_reduce.simulation.engine``).
"""

import numpy as np
from _noise_streams import synth

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule


def schedule(nrows=256, ncols=128, nchannels=4, nframes=20, phantom_reads=4):
    g = DetectorGeometry(nrows, ncols, nchannels, ref_border=4)
    return ReadoutSchedule(g, skip=1, ref_reads=8, phantom_reads=phantom_reads,
                           nframes=nframes, frame_overhead=200)


def dark(s, components, seed, offset=1000.0, dark_current=5.0):
    """Raw ramps of ``components`` (dicts as in a scene) drawn at the schedule's samples,
    on a pixel offset and a dark ramp (which characterize must not see)."""
    g = s.geometry
    rng = np.random.default_rng(seed)
    total = s.nframes * s.frame_samples
    frames = np.arange(s.nframes)[:, None, None] * s.frame_samples
    pix = frames + s.pixel_samples()[None]
    c = s.phantom_reads
    data = np.zeros(pix.shape)
    phantom = np.zeros((s.nframes, s.n_reads, g.nchannels))
    chan = g.channel_of_column()
    par = g.column_offsets() % 2
    for comp in components:
        coeffs = (comp.get("alpha", 0.0), comp.get("beta", 0.0), comp.get("gamma", 0.0))
        acn = comp.get("acn", False)
        common = comp.get("scope", "channel") == "common"
        nstreams = 1 if common else g.nchannels * (2 if acn else 1)
        x = synth(total, coeffs, rng, nstreams=nstreams, pad=4, fs=g.pixel_rate,
                  exponent=comp.get("exponent", 1.3))
        vis = comp.get("visibility", "pixels")
        if vis in ("pixels", "both"):
            stream = np.zeros_like(chan) if common else (2 * chan + par if acn else chan)
            data += x[stream[None, None, :], pix]
        if vis in ("phantom", "both") and c:
            psamp = frames + s.phantom_samples()[None]  # (N, R, c)
            ppar = (np.arange(c) - c) % 2
            for ch in range(g.nchannels):
                idx = (np.zeros(c, int) if common
                       else 2 * ch + ppar if acn else np.full(c, ch))
                phantom[:, :, ch] += np.mean(x[idx[None, None, :], psamp], axis=-1)
    light = ~g.reference_pixel_mask()[s.rows]  # (R, ncols)
    data += offset + dark_current * np.arange(s.nframes)[:, None, None] * light[None]
    return Exposure.from_arrays(data.astype(np.float64), s,
                                phantom=phantom if c else None)
