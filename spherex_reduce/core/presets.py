"""Named detector layouts: ``geometry: {preset: NAME}``.

Each preset is a set of ``geometry:`` values checked against public
documentation (cited below); keys given next to ``preset`` override the
preset's.  A value the documentation found does not settle is left out of the
preset (the field keeps its default) and said so here and in the docs:

``H2RG``
    SPHEREx: 2048 x 2048, 32 outputs of 64 columns, 4-pixel reference border,
    every channel read left to right, 100 kHz (Heaton et al., "Noise Reduction
    Methods for Large-Scale Intensity Mapping Measurements with Infrared
    Detector Arrays", section 1 and Table 3; the package's defaults).
``H4RG-10``
    Roman WFI: 4096 x 4096, 32 outputs of 128 columns read along the columns
    with alternating readout direction (``romanisim.l1.frame_read_times``,
    romanisim.readthedocs.io), 4-pixel border.  The pixel rate is not given
    there: the preset leaves ``pixel_rate`` at its default; state it, or the
    readout's ``frame_time``.
``WFC3-IR``
    HST WFC3/IR: 1024 x 1024, four 512 x 512 quadrants each read from its
    outer corner, along each row toward the horizontal mid-point, then inward
    row by row; 5 rows and columns of reference pixels all around (WFC3
    Instrument Handbook, section 5.6.1, hst-docs.stsci.edu).  The handbook
    gives 2.93 s to read the array (section 7.7.2), not a pixel rate: the
    preset leaves ``pixel_rate`` at its default; give ``readout.frame_time``.
``SIDECAR``
    JWST SIDECAR ASIC, detector orientation: 2048 x 2048, 4 outputs of
    512 columns, 10 us per pixel (100 kHz) (JWST User Documentation, "NIRCam
    Detector Readout", jwst-docs.stsci.edu), 4-pixel border, fast-scan
    direction alternating between outputs (``scan: alternate``, the package's
    JWST convention: the text found does not state the direction).
``SIDECAR-science``
    The same, in NIRSpec's science orientation: the stored image is the
    transpose, each output a band of 512 rows read along the columns
    (``channels: rows``).
"""

__all__ = ["FULL_ARRAY", "PRESETS", "apply_preset", "apply_window_preset", "check_preset"]

_SIDECAR = {"nrows": 2048, "ncols": 2048, "nchannels": 4, "ref_border": 4,
            "scan": "alternate", "pixel_rate": 100_000.0}

#: The geometry values of each preset.
PRESETS = {
    "H2RG": {"nrows": 2048, "ncols": 2048, "nchannels": 32, "ref_border": 4, "scan": "same",
             "pixel_rate": 100_000.0},
    "H4RG-10": {"nrows": 4096, "ncols": 4096, "nchannels": 32, "ref_border": 4,
                "scan": "alternate"},
    "WFC3-IR": {"nrows": 1024, "ncols": 1024, "nchannels": 4, "ref_border": 5,
                "channels": "quadrants", "first_corner": "outer", "fast_axis": "rows"},
    "SIDECAR": _SIDECAR,
    "SIDECAR-science": {**_SIDECAR, "channels": "rows"},
}



def check_preset(name, what="preset"):
    """Refuse a ``name`` that is not one of `PRESETS` (``what`` names it in the message).

    Raises
    ------
    ValueError
        Naming the known presets.
    """
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"{what} {name!r} is not a known preset; known: {', '.join(PRESETS)}")


def apply_preset(values):
    """The ``geometry:`` values with those of their ``preset`` filled in.

    Parameters
    ----------
    values : mapping
        ``geometry:`` keys as given; ``preset`` names one of `PRESETS`.

    Returns
    -------
    dict
        The preset's values, overridden by the keys given (``preset`` kept).

    Raises
    ------
    ValueError
        An unknown preset, naming the known ones.

    Examples
    --------
    >>> from spherex_reduce.core.presets import apply_preset
    >>> g = apply_preset({"preset": "WFC3-IR", "ref_border": 4})
    >>> g["nrows"], g["channels"], g["ref_border"]
    (1024, 'quadrants', 4)
    """
    values = dict(values or {})
    name = values.get("preset")
    if name is None:
        return values
    check_preset(name, "geometry.preset")
    return {**PRESETS[name], **values}


#: With a ``window:``, a preset describes the full array the window lies in: these of
#: its values fill the window's fields (keys given win), the others the geometry's.
FULL_ARRAY = {"nrows": "full_nrows", "ncols": "full_ncols", "nchannels": "full_nchannels",
              "scan": "full_scan", "ref_border": "full_ref_border"}


def apply_window_preset(geometry, window):
    """The ``geometry:`` and ``window:`` values of a window whose full array is a preset.

    The preset's size, channels, scan and reference border are the full
    array's (`FULL_ARRAY`: the window's ``full_*`` fields, unless given); its
    other values (``pixel_rate``, ``channels``...) fill the geometry's, whose
    ``nrows`` and ``ncols`` stay the window's.

    Parameters
    ----------
    geometry, window : mapping
        The sections as given; ``geometry['preset']`` names one of `PRESETS`.

    Returns
    -------
    geometry, window : dict

    Raises
    ------
    ValueError
        An unknown preset, naming the known ones.

    Examples
    --------
    >>> from spherex_reduce.core.presets import apply_window_preset
    >>> g, w = apply_window_preset({"preset": "H4RG-10", "nrows": 64, "ncols": 64},
    ...                            {"first_row": 0, "first_column": 0})
    >>> g["nrows"], "nchannels" in g, w["full_nrows"], w["full_nchannels"], w["full_scan"]
    (64, False, 4096, 32, 'alternate')
    """
    filled = apply_preset({"preset": geometry["preset"]})
    window = {**{full: filled[key] for key, full in FULL_ARRAY.items() if key in filled},
              **window}
    geometry = {**{k: v for k, v in filled.items() if k not in FULL_ARRAY}, **geometry}
    return geometry, window
