"""The JWST pipeline's reference-pixel correction (``refpix``) on NGHXRG's cubes, in jwst's venv.

Run by ``bench_reference_peers.py`` with the interpreter of its own venv (jwst is never
installed next to this package: it pins numpy, astropy and stdatamodels of its own):
``python jwst_refpix_peer.py REQUEST.json``.  It imports jwst, never ``spherex_reduce``.

``REQUEST.json``: ``{"cubes": [FITS, ...], "out": DIR, "modes": {NAME: {"odd_even_columns":
bool, "use_side_ref_pixels": bool}, ...}}``.  Each cube (a primary HDU ``(groups, 2048,
2048)`` in DN, detector orientation, a 4-pixel reference border, four outputs of 512
columns as SIDECAR reads them) is written as a level-1b ramp the way the pipeline writes
one: a `~stdatamodels.jwst.datamodels.RampModel` of one integration with a NIRCam-like
``meta`` (full frame, 4 outputs, ``fastaxis`` 1 and ``slowaxis`` 2, so that the science
and detector frames are one), ``pixeldq`` flagging the border ``REFERENCE_PIXEL``, saved
as ``DIR/STEM_uncal.fits``.  For each mode that file is opened again and corrected by
``jwst.refpix.reference_pixels.correct_model`` with the step's defaults for the rest
(``side_smoothing_length`` 11, ``side_gain`` 1, ``siglimit`` 3, the running-median side
algorithm), timed around that call alone, and saved as ``DIR/STEM_NAME_refpix.fits``
(its ``SCI`` extension is read back).  Prints one JSON line per cube and mode
(``cube``, ``mode``, ``output``, ``seconds``, ``status``) and a first line of versions.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
from astropy.io import fits

BORDER = 4


def ramp_model(cube):
    """A level-1b `RampModel` of one integration holding ``cube`` (groups, rows, columns)."""
    from stdatamodels.jwst import datamodels
    from stdatamodels.jwst.datamodels import dqflags

    ngroups, ny, nx = cube.shape
    pixeldq = np.zeros((ny, nx), np.uint32)
    ref = np.zeros((ny, nx), bool)
    ref[:BORDER] = ref[-BORDER:] = True
    ref[:, :BORDER] = ref[:, -BORDER:] = True
    pixeldq[ref] = dqflags.pixel["REFERENCE_PIXEL"]
    model = datamodels.RampModel(data=np.asarray(cube, np.float32)[None],
                                 pixeldq=pixeldq,
                                 groupdq=np.zeros((1, ngroups, ny, nx), np.uint8))
    m = model.meta
    m.instrument.name = "NIRCAM"
    m.instrument.detector = "NRCA2"
    m.instrument.channel = "SHORT"
    m.instrument.module = "A"
    m.instrument.filter = "F210M"
    m.instrument.pupil = "CLEAR"
    m.exposure.type = "NRC_DARK"
    m.exposure.readpatt = "RAPID"
    m.exposure.nints = 1
    m.exposure.ngroups = ngroups
    m.exposure.nframes = 1
    m.exposure.groupgap = 0
    m.exposure.noutputs = 4
    m.exposure.zero_frame = False
    m.subarray.name = "FULL"
    m.subarray.xstart, m.subarray.ystart = 1, 1
    m.subarray.xsize, m.subarray.ysize = nx, ny
    m.subarray.fastaxis, m.subarray.slowaxis = 1, 2
    m.observation.date = "2026-11-29"
    m.observation.time = "00:00:00"
    m.cal_step.refpix = "SKIPPED"
    return model


def main():
    import jwst
    import stcal
    import stdatamodels
    from jwst.refpix import reference_pixels
    from jwst.refpix.refpix_step import RefPixStep
    from stdatamodels.jwst import datamodels

    request = json.loads(Path(sys.argv[1]).read_text())
    out = Path(request["out"])
    out.mkdir(parents=True, exist_ok=True)
    spec = RefPixStep()
    print(json.dumps({"jwst": jwst.__version__, "stdatamodels": stdatamodels.__version__,
                      "stcal": stcal.__version__, "numpy": np.__version__}), flush=True)
    kernel = {"refpix_algorithm": "median", "sirs_kernel_model": None,
              "sigreject": spec.sigreject, "gaussmooth": spec.gaussmooth,
              "halfwidth": spec.halfwidth}
    for path in request["cubes"]:
        path = Path(path)
        level1b = out / f"{path.stem}_uncal.fits"
        with ramp_model(fits.getdata(path)) as model:
            model.save(level1b)
        for name, mode in request["modes"].items():
            with datamodels.RampModel(level1b) as model:
                t0 = time.perf_counter()
                status = reference_pixels.correct_model(
                    model, bool(mode["odd_even_columns"]), bool(mode["use_side_ref_pixels"]),
                    spec.side_smoothing_length, spec.side_gain, spec.odd_even_rows, kernel,
                    spec.siglimit)
                seconds = time.perf_counter() - t0
                model.meta.cal_step.refpix = ("COMPLETE" if status == reference_pixels.REFPIX_OK
                                              else "SKIPPED")
                result = out / f"{path.stem}_{name}_refpix.fits"
                model.save(result)
            print(json.dumps({"cube": str(path), "mode": name, "output": str(result),
                              "seconds": seconds, "status": int(status)}), flush=True)


if __name__ == "__main__":
    main()
