"""The package uses astropy's public API only: no private names of astropy anywhere."""

import re
from pathlib import Path

import spherex_reduce

#: Private names of astropy (mostly ``astropy.io.fits``) that a writer or reader is tempted by.
PRIVATE = ("_header", "_calculate_checksum", "_calculate_datasum", "_compute_checksum",
           "_char_encode", "_encode_byte", "_get_timestamp", "_File", "_BaseHDU", "_ValidHDU",
           "_file", "_data_loaded", "_has_data", "_get_raw_data", "_data_offset", "_datLoc",
           "_writeto", "_prewriteto", "_postwriteto", "_writeheader", "_writedata",
           "_verify_checksum_datasum", "_output_checksum", "_hdu_list", "_readfrom")

ATTRIBUTE = re.compile(r"(?<!\bself)(?<!\bcls)\.(" + "|".join(PRIVATE) + r")\b")  # not our own
PRIVATE_IMPORT = re.compile(r"^\s*(from\s+astropy[\w.]*\s+import\s+[^#]*\b_\w+|"
                            r"(from|import)\s+astropy(\.\w+)*\._\w+)", re.M)


def private_astropy_uses(root):
    """``file:line: text`` of every use of a private astropy name under ``root``."""
    found = []
    for path in sorted(Path(root).rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if ATTRIBUTE.search(code) or PRIVATE_IMPORT.search(code):
                found.append(f"{path}:{number}: {line.strip()}")
    return found


def test_the_patterns_catch_what_they_should(tmp_path):
    (tmp_path / "m.py").write_text(
        "helper._header = header\n"
        "x = fits.ImageHDU()._calculate_checksum(0)\n"
        "from astropy.io.fits.file import _File\n"
        "from astropy.io.fits._utils import thing\n"
        "self._header = 1  # our own attribute\n"
        "def _header(sc): pass\n"
        "hdu.fileinfo()['datLoc']\n")
    assert [line.split(": ", 1)[0].rsplit(":", 1)[1] for line in
            private_astropy_uses(tmp_path)] == ["1", "2", "3", "4"]


def test_no_private_astropy_api_in_the_package():
    assert private_astropy_uses(Path(spherex_reduce.__file__).parent) == []
