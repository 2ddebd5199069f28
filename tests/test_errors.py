"""``arlight.errors.read_text``: the one place input files are read as text."""

import pytest

from arlight.errors import InputError, read_text


def test_read_text_names_the_file_and_what_it_is(tmp_path):
    """Rejects a reader that lets FileNotFoundError/UnicodeDecodeError escape or drops the
    file name."""
    good = tmp_path / "a.txt"
    good.write_text("héllo", encoding="utf-8")
    assert read_text(good, "poses file") == "héllo"
    with pytest.raises(InputError, match="poses file not found") as e:
        read_text(tmp_path / "missing.txt", "poses file")
    assert e.value.file == str(tmp_path / "missing.txt")
    bad = tmp_path / "b.txt"
    bad.write_bytes(b"\xff\xfe\xfa")
    with pytest.raises(InputError, match="cannot read the light file") as e:
        read_text(bad, "light file")
    assert e.value.file == str(bad)
    with pytest.raises(InputError, match="cannot read the rig"):
        read_text(tmp_path, "rig")  # a folder
