"""``arlight import-mitsuba``: a Mitsuba XML scene imported and rendered with ``reference``
agrees with Mitsuba's own render of the XML (issue 9 acceptance)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from arlight.errors import InputError
from arlight.io.images import write_exr

XML = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="6"/></integrator>
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0,1.2,3" target="0,0.3,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="cube" id="box">
    <transform name="to_world"><scale value="0.25"/><rotate y="1" angle="30"/>
      <translate x="-0.6" y="0.25" z="-0.3"/></transform>
    <bsdf type="twosided"><bsdf type="conductor">
      <rgb name="specular_reflectance" value="0.8"/></bsdf></bsdf></shape>
  <shape type="sphere" id="ball"><point name="center" x="0.6" y="0.3" z="0.1"/>
    <float name="radius" value="0.3"/><bsdf type="dielectric"/></shape>
  <shape type="ply" id="blob"><string name="filename" value="blob.ply"/>
    <transform name="to_world"><translate x="0" y="0.35" z="-0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.5, 0.7"/></bsdf></shape>
  <shape type="rectangle" id="lamp">
    <transform name="to_world"><scale value="0.3"/><rotate x="1" angle="90"/>
      <translate x="0.3" y="1.8" z="0.3"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
    <emitter type="area"><rgb name="radiance" value="8, 7.5, 7"/></emitter></shape>
  <emitter type="envmap"><string name="filename" value="sky.exr"/><float name="scale" value="0.8"/>
    <transform name="to_world"><rotate y="1" angle="40"/></transform></emitter>
</scene>
"""


@pytest.fixture(scope="module")
def xml_scene(tmp_path_factory):
    """The test scene: rectangle, cube, sphere, a PLY mesh with file normals, conductor,
    dielectric, envmap and area light."""
    folder = tmp_path_factory.mktemp("mitsuba")
    blob = trimesh.creation.icosphere(2, radius=0.3)
    blob.vertices[:, 1] *= 0.7
    normals = blob.vertex_normals.copy()
    mesh = trimesh.Trimesh(blob.vertices, blob.faces, process=False)
    mesh._cache["vertex_normals"] = normals  # trimesh writes its cached normals
    (folder / "blob.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, vertex_normal=True))
    h, w = 16, 32
    theta = (np.arange(h) + 0.5) / h * np.pi
    sky = np.zeros((h, w, 3), np.float32)
    sky[:] = (0.4 + 0.8 * np.cos(theta).clip(0))[:, None, None] * np.array([0.8, 0.9, 1.1])
    sky[:, 5:8] *= 3.0  # a brighter band: makes the rotation visible
    write_exr(folder / "sky.exr", sky)
    (folder / "scene.xml").write_text(XML)
    return folder


def test_import_matches_mitsubas_own_render(xml_scene, tmp_path):
    import mitsuba as mi

    from arlight.importers.mitsuba import import_mitsuba
    from arlight.methods import RenderSettings, get_method
    from arlight.scene.load import load_scene, render_settings_for
    from arlight.stats import agreement_fraction
    from tests.conftest import with_constant_frame

    world = import_mitsuba(xml_scene / "scene.xml", tmp_path / "world.toml")
    scene = load_scene(world)
    kinds = {s.type for s in scene.shapes}
    assert kinds == {"rectangle", "mesh", "sphere"}
    blob = next(s for s in scene.shapes if s.name == "blob")
    assert blob.mesh.normals_from == "file"
    assert {x.type for x in scene.lights} == {"area", "envmap"}
    given = render_settings_for(world)
    assert (given["max_depth"], given["spp"]) == (6, 16)

    ours = get_method("reference")(with_constant_frame(scene),
                                   RenderSettings(spp=256, max_depth=6, seed=3))
    mscene = mi.load_file(str(xml_scene / "scene.xml"))
    batches = np.stack([np.array(mi.render(mscene, spp=16, seed=100 + i))[..., :3]
                        for i in range(32)])
    mean = batches.mean(axis=0)
    se = batches.std(axis=0, ddof=1) / np.sqrt(len(batches))
    frac = agreement_fraction(ours.mixed, ours.stderr["mixed"], mean, se)
    print(f"agreement within 3 SE: {frac:.4f}")
    assert frac >= 0.99, frac
    assert abs(ours.mixed.mean() / mean.mean() - 1) < 0.02


def test_roles_by_name_or_glob_and_unknown_names(xml_scene, tmp_path):
    from arlight.importers.mitsuba import import_mitsuba
    from arlight.scene.load import load_scene

    sc = load_scene(import_mitsuba(xml_scene / "scene.xml", tmp_path / "w.toml",
                                   virtual=["b*"]))
    assert {s.name for s in sc.virtual_shapes} == {"box", "ball", "blob"}
    with pytest.raises(InputError, match="no shape matches 'teapot'"):
        import_mitsuba(xml_scene / "scene.xml", tmp_path / "w2.toml", virtual=["teapot"])


def test_unsupported_plugin_names_the_element(xml_scene, tmp_path):
    from arlight.importers.mitsuba import import_mitsuba

    xml = tmp_path / "plastic.xml"
    xml.write_text(XML.replace('<bsdf type="dielectric"/>', '<bsdf type="plastic"/>'))
    (tmp_path / "blob.ply").write_bytes((xml_scene / "blob.ply").read_bytes())
    (tmp_path / "sky.exr").write_bytes((xml_scene / "sky.exr").read_bytes())
    with pytest.raises(InputError) as info:
        import_mitsuba(xml, tmp_path / "w.toml")
    assert info.value.field == 'bsdf of shape "ball"'
    assert 'type="plastic"' in str(info.value)
    assert not (tmp_path / "w.toml").exists()
