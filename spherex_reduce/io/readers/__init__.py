"""The FITS readers behind `spherex_reduce.io.sources.open_input`.

``read_exposure`` (`~spherex_reduce.io.read`: the reader a file's layout needs),
``fits_read`` (our layout and any FITS file, checked), ``description`` (what a
reader needs before the pixels), ``frames`` (a raw ramp a band of reads at a
time), ``read_files`` (one file per read), ``extension_reads`` (a ramp's reads
as ``SCI`` extensions), ``jwst_level1`` (a JWST file in its own keywords'
meaning), ``roman_l1`` (a Roman level-1 ASDF file), ``flags`` (whose ``DQ``
bits), ``pixels`` (stored integers to physical values), ``stable_file`` (reads
of a file that must not change), ``ccddata`` (a reduced image as astropy's
``CCDData``, and the astropy I/O registry's format ``spherex_reduce``).
"""
