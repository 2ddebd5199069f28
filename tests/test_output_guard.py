"""The output guard: inputs are never replaced, files arlight did not write are never
replaced, arlight's own earlier outputs may be."""

from __future__ import annotations

import os

import pytest

from arlight.errors import InputError
from arlight.output_guard import (
    LEDGER,
    check_outputs,
    check_writable_file,
    record_written,
    written_by_arlight,
)


def test_output_equal_to_an_input_is_refused_naming_both(tmp_path):
    scene = tmp_path / "scene.xml"
    scene.write_text("<scene/>")
    with pytest.raises(InputError) as e:
        check_outputs({"-o": tmp_path / "." / "scene.xml"}, [scene])
    assert "scene.xml" in str(e.value) and "-o" in str(e.value)
    assert e.value.field == "-o"


def test_a_symlink_to_an_input_is_the_input(tmp_path):
    """Bug caught: comparing paths as written instead of resolved."""
    mesh = tmp_path / "mesh.ply"
    mesh.write_text("ply")
    os.symlink(mesh, tmp_path / "link.ply")
    with pytest.raises(InputError, match="input"):
        check_outputs({"--mesh": [tmp_path / "link.ply"]}, [mesh], overwrite=True)


def test_existing_foreign_file_is_refused_unless_overwrite(tmp_path):
    mine = tmp_path / "notes.json"
    mine.write_text("{}")
    with pytest.raises(InputError, match="not a file arlight wrote"):
        check_outputs({"-o": mine}, [])
    check_outputs({"-o": mine}, [], overwrite=True)


def test_own_earlier_output_is_replaceable_until_edited(tmp_path):
    """Bug caught: a ledger keyed by name alone (a user's edit would then be overwritten)."""
    out = tmp_path / "light.json"
    out.write_text('{"a": 1}')
    record_written([out])
    assert (tmp_path / LEDGER).is_file() and written_by_arlight(out)
    check_outputs({"-o": out}, [])
    out.write_text('{"a": 2}')  # the user edits it
    assert not written_by_arlight(out)
    with pytest.raises(InputError):
        check_outputs({"-o": out}, [])


def test_the_same_file_twice_is_refused(tmp_path):
    with pytest.raises(InputError, match="twice"):
        check_outputs({"-o": tmp_path / "a.ply", "--mesh": tmp_path / "sub" / ".." / "a.ply"},
                      [])


def test_unwritable_places(tmp_path):
    (tmp_path / "afile").write_text("x")
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    for path, words in [(tmp_path / "afile" / "x.json", "not a folder"),
                        (tmp_path / "dangling", "dangling"),
                        (tmp_path / "dangling" / "x.json", "dangling"),
                        (tmp_path, "folder")]:
        with pytest.raises(InputError, match=words):
            check_writable_file(path, "-o")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        if not os.access(ro, os.W_OK):  # root ignores mode bits
            with pytest.raises(InputError, match="not writable"):
                check_writable_file(ro / "x.json", "-o")
    finally:
        ro.chmod(0o755)


def test_the_ledger_is_never_an_output(tmp_path):
    """Bug fixed: -o .arlight-written.json would have replaced the ledger itself."""
    with pytest.raises(InputError, match="record"):
        check_outputs({"-o": tmp_path / LEDGER}, [])


def test_referenced_files_lists_the_files_a_scene_names(tmp_path):
    from arlight.output_guard import referenced_files

    (tmp_path / "m.ply").write_text("ply")
    (tmp_path / "s.toml").write_text('[[shapes]]\nfile = "m.ply"\nname = "not-a-file"\n')
    assert set(referenced_files(tmp_path / "s.toml")) == {tmp_path / "s.toml",
                                                          tmp_path / "m.ply"}


def test_output_folder_under_a_dangling_symlink_or_mkdir_refused_is_input_error(
        tmp_path, monkeypatch):
    """Old behaviour: exit 1 (FileExistsError / OSError in mkdir) for staged_output."""
    from arlight.staged_output import StagedOutput, check_output_dir

    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    with pytest.raises(InputError, match="dangling"):
        check_output_dir(tmp_path / "dangling" / "out")
    import errno
    from pathlib import Path

    def refuse(*_a, **_k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(Path, "mkdir", refuse)
    with pytest.raises(InputError, match="read-only"), StagedOutput(tmp_path / "o" / "x",
                                                                    "test"):
        pass
