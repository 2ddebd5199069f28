"""``import-mitsuba`` never destroys an input or a person's file, and re-runs onto its own
output (issue #28)."""

from __future__ import annotations

import pytest
import trimesh

from arlight.errors import InputError
from arlight.importers.mitsuba import import_mitsuba, xml_references

XML = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/>
    </film></sensor>
  <shape type="ply" id="blob"><string name="filename" value="scene.blob.ply"/>
    <bsdf type="diffuse"/></shape>
</scene>
"""


@pytest.fixture
def xml(tmp_path):
    mesh = trimesh.creation.icosphere(1, radius=0.2)
    (tmp_path / "scene.blob.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh))
    (tmp_path / "scene.xml").write_text(XML.format(fov=45))
    return tmp_path / "scene.xml"


def test_references_are_inputs(xml):
    assert xml.parent / "scene.blob.ply" in xml_references(xml)


def test_output_onto_the_xml_or_a_referenced_mesh_is_refused(xml):
    """Old behaviour: -o scene.xml replaced the XML; -o scene.toml wrote scene.blob.ply over
    the mesh the XML reads."""
    before = {p.name: p.read_bytes() for p in xml.parent.iterdir()}
    for out, word in ((xml, "scene.xml"), (xml.with_suffix(".toml"), "scene.blob.ply")):
        with pytest.raises(InputError, match=word):
            import_mitsuba(xml, out)
    assert {p.name: p.read_bytes() for p in xml.parent.iterdir()} == before


def test_a_persons_mesh_beside_the_output_is_kept_unless_overwrite(xml, tmp_path):
    out = tmp_path / "out" / "w.toml"
    out.parent.mkdir()
    (out.parent / "w.blob.ply").write_text("mine")
    with pytest.raises(InputError, match="w.blob.ply"):
        import_mitsuba(xml, out)
    assert (out.parent / "w.blob.ply").read_text() == "mine" and not out.exists()
    import_mitsuba(xml, out, overwrite=True)
    import_mitsuba(xml, out)  # its own earlier output: replaced without --overwrite
    assert out.is_file() and not any(p.name.startswith(".w.toml.tmp") for p in
                                     out.parent.iterdir())


def test_nan_fov_and_folder_output_are_input_errors(xml, tmp_path):
    """Old behaviour: exit 1 (internal error) for both."""
    bad = tmp_path / "nan.xml"
    bad.write_text(XML.format(fov="nan"))
    with pytest.raises(InputError, match="fov"):
        import_mitsuba(bad, tmp_path / "n.toml")
    with pytest.raises(InputError, match="folder"):
        import_mitsuba(xml, tmp_path)
    assert not (tmp_path / "n.toml").exists()


def test_memory_bound_names_force(xml, tmp_path, monkeypatch):
    import arlight.bounds as B

    monkeypatch.setattr(B, "available_memory", lambda: 1000.0)
    with pytest.raises(InputError, match="--force"):
        import_mitsuba(xml, tmp_path / "b.toml")
    import_mitsuba(xml, tmp_path / "b.toml", force=True)
