"""Names as text a FITS header card can hold: printable ASCII, given back exactly."""

import os

import pytest
from astropy.io import fits

from spherex_reduce.io.header_text import header_text, name_from_header

NAMES = ["dàrk.fits", "brüit.ecsv", "é.yaml", "a\nb.yaml", "tab\there", "read_1²1.fits",
         "read_１.fits", "C:\\data\\raw.fits", "back\\xe9slash", "it's\"quoted\"", "\x7fdel",
         "emoji😀.fits", os.fsdecode(b"raw\xff\xfe.fits")]  # the last: undecodable bytes


@pytest.mark.parametrize("name", NAMES)
def test_a_name_goes_into_a_card_and_comes_back(name):
    text = header_text(name)
    assert all(0x20 <= ord(c) <= 0x7E for c in text), text
    header = fits.Header()
    header["FILE"] = text
    header.add_history(f"input {text} read")
    card = fits.Card.fromstring(header.cards["FILE"].image)  # as written in a file
    assert name_from_header(card.value) == name
    assert name_from_header(str(header["HISTORY"][0]).split(" ")[1]) == name


def test_printable_ascii_without_a_backslash_is_kept():
    for name in ("raw.fits", "dir/read_10.fits", "a b+c=d~e.fits"):
        assert header_text(name) == name
    assert header_text("a\\b") == "a\\\\b"  # the one ASCII character escaped: the escape


def test_a_path_is_its_text():
    from pathlib import PurePosixPath

    assert header_text(PurePosixPath("d/é.fits")) == "d/\\xe9.fits"
