"""Mitsuba XML area emitters on sphere and rectangle shapes as our lights with extent
(docs/MODEL.md, "Lights with extent"): fields against Mitsuba's own reading of the same
file, the TOML -> XML -> TOML round trip of the soft-shadow scene (same fields, same image),
and one-line errors for area lights outside the model."""
from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from renderer.scene import SceneError, load_scene

ROOT = Path(__file__).resolve().parent.parent

XML = """<scene version="3.0.0">
  <integrator type="direct"><integer name="emitter_samples" value="9"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 1, 5" target="0, 0.5, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
    </film>
  </sensor>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><rotate x="1" angle="-90"/><scale value="3"/></transform>
    <bsdf type="diffuse"/>
  </shape>
  <shape type="sphere" id="bulb">
    <point name="center" x="0.1" y="0.2" z="-0.3"/>
    <float name="radius" value="0.25"/>
    <transform name="to_world"><scale value="2"/><translate x="0.5" y="1.5" z="0"/>
    </transform>
    <emitter type="area"><rgb name="radiance" value="4, 2, 1"/></emitter>
  </shape>
  <shape type="rectangle" id="panel">
    <transform name="to_world">
      <scale x="0.5" y="0.3" z="1"/><rotate x="1" angle="70"/><rotate y="1" angle="20"/>
      <translate x="-0.4" y="2" z="0.3"/>
    </transform>
    FLIP
    <emitter type="area"><rgb name="radiance" value="3"/></emitter>
  </shape>
</scene>
"""


def _load(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path, **kw)
    return scene, [str(w.message) for w in caught]


@pytest.mark.parametrize("flip", [False, True])
def test_sphere_and_rectangle_area_lights_read_as_mitsuba_reads_them(tmp_path, flip):
    """Centre, radius, edges, emitting side and area as Mitsuba's own shapes have them
    (``sample_position``, ``surface_area``, ``bbox``), intensity ``L_e π r²`` / ``L_e A``;
    the shapes are lights, not geometry (a warning each), and ``emitter_samples`` is the
    shadow sample count."""
    mitsuba = pytest.importorskip("mitsuba")
    from reference import mitsuba_variant
    mitsuba_variant()
    mi = mitsuba
    path = tmp_path / "area.xml"
    path.write_text(XML.replace("FLIP", '<boolean name="flip_normals" value="true"/>'
                                if flip else ""))
    scene, warned = _load(path)
    assert [o.name for o in scene.objects] == ["floor"]
    assert scene.settings.shadow_samples == 9
    assert sum("read as a" in w and "not geometry" in w for w in warned) == 2
    bulb, panel = scene.lights
    assert (bulb.name, bulb.shape, panel.name, panel.shape) == \
        ("bulb", "sphere", "panel", "rectangle")
    ms = {s.id(): s for s in mi.load_file(str(path)).shapes()}
    box = ms["bulb"].bbox()
    np.testing.assert_allclose(bulb.position, np.array(box.center()), atol=1e-6)
    assert bulb.radius == pytest.approx(float(box.extents()[0]) / 2, rel=1e-6)
    assert bulb.radius == pytest.approx(0.5)
    np.testing.assert_allclose(bulb.intensity, np.array([4, 2, 1]) * math.pi * 0.25)
    assert bulb.falloff == "inverse_square"

    def at(u, v):
        ps = ms["panel"].sample_position(0.0, mi.Point2f(u, v))
        return np.array(ps.p).ravel(), np.array(ps.n).ravel()
    c, n = at(0.5, 0.5)
    np.testing.assert_allclose(panel.position, c, atol=1e-6)
    ours_n = np.cross(panel.edge_u, panel.edge_v)
    np.testing.assert_allclose(ours_n / np.linalg.norm(ours_n), n, atol=1e-6)
    edges = [2 * (at(1.0, 0.5)[0] - c), 2 * (at(0.5, 1.0)[0] - c)]
    ours = [panel.edge_u, panel.edge_v] if not flip else [panel.edge_v, panel.edge_u]
    np.testing.assert_allclose(ours, edges, atol=1e-6)
    area = float(ms["panel"].surface_area()[0])
    assert panel.area == pytest.approx(area, rel=1e-6) and not panel.two_sided
    np.testing.assert_allclose(panel.intensity, 3 * panel.area)


def _tiny(scene):
    from renderer.render import render
    return render(scene.with_size(12, 10)).image


def _soft_variant(tmp_path, kind: str) -> Path:
    text = (ROOT / "scenes" / "cornell_soft.toml").read_text()
    if kind == "rectangle":      # a two-sided panel and a point light, in that order
        text = re.sub(r'type = "sphere"\ncenter = \[0.0, 1.75, 0.2\]\nradius = 0.15',
                      'type = "rectangle"\ncenter = [0.1, 1.7, 0.2]\n'
                      'edge_u = [0.4, 0.0, 0.05]\nedge_v = [0.0, 0.1, 0.3]\n'
                      'two_sided = true', text)
        assert 'two_sided = true' in text
        text += ('\n[[lights]]\nname = "fill"\nposition = [0.5, 1.2, 1.5]\n'
                 'intensity = 0.3\nfalloff = "inverse_square"\n')
    path = tmp_path / f"{kind}.toml"
    path.write_text(text)
    return path


def _light_fields(scene):
    out = []
    for lt in scene.lights:
        out.append((lt.shape, lt.falloff, lt.two_sided, lt.radius, tuple(lt.position),
                    tuple(lt.intensity),
                    None if lt.edge_u is None else (tuple(lt.edge_u), tuple(lt.edge_v))))
    return out


def _assert_same_lights(a, b):
    """The same lights: a sphere's fields as float64 (radiance π r² back to intensity:
    rounding only), a rectangle's to float32 rounding (the export writes its ``to_world``
    as Mitsuba's float32 transform; the renderer's light data are float32 anyway)."""
    assert len(a.lights) == len(b.lights)
    for la, lb in zip(_light_fields(a), _light_fields(b)):
        rtol = 1.2e-7 if la[0] == "rectangle" else 1e-14
        assert la[:3] == lb[:3], (la, lb)
        np.testing.assert_allclose(la[3], lb[3], rtol=rtol)
        np.testing.assert_allclose(la[4], lb[4], rtol=rtol)
        np.testing.assert_allclose(la[5], lb[5], rtol=rtol)
        if la[6] is not None:
            np.testing.assert_allclose(la[6], lb[6], rtol=rtol)


@pytest.mark.parametrize("kind", ["sphere", "rectangle"])
def test_toml_xml_toml_round_trip_keeps_the_lights_and_the_image(tmp_path, kind):
    """``whitted export`` then ``whitted convert``: the lights with extent (shape, centre,
    radius or edges, two-sidedness, falloff, intensity), the shadow samples and, at a tiny
    size, the image bit for bit, after the XML and after the TOML."""
    pytest.importorskip("mitsuba")
    from whitted.cli import main
    src = _soft_variant(tmp_path, kind)
    scene = load_scene(src)
    xml, back_toml = tmp_path / "s.xml", tmp_path / "back.toml"
    assert main(["export", str(src), "--mitsuba-xml", str(xml)]) == 0
    from_xml, _ = _load(xml)
    assert main(["convert", str(xml), str(back_toml)]) == 0
    back, _ = _load(back_toml)
    image = _tiny(scene)
    assert image.max() > 0
    for other in (from_xml, back):
        _assert_same_lights(scene, other)
        assert other.settings.shadow_samples == scene.settings.shadow_samples == 4
        assert np.array_equal(_tiny(other), image)


@pytest.mark.parametrize("old, new, message", [
    ('<shape type="rectangle" id="floor">',
     '<shape type="cube" id="floor">\n    <emitter type="area"/>', 'on a <shape type="cube">'),
    ('<rgb name="radiance" value="3"/>', '<rgb name="radiance" value="-3"/>',
     "radiance: expected values >= 0"),
    ('<float name="radius" value="0.25"/>', '<float name="radius" value="0"/>',
     "radius: expected a number > 0"),
    ('<scale value="2"/><translate', '<scale x="2" y="1" z="1"/><translate',
     "a sphere light scales uniformly"),
    ('<emitter type="area"><rgb name="radiance" value="3"/>',
     '<emitter type="point"><rgb name="radiance" value="3"/>',
     "only an area emitter makes a light"),
    ('<integer name="emitter_samples" value="9"/></integrator>',
     '<integer name="emitter_samples" value="9"/></integrator>\n  <emitter type="area"/>',
     "an area emitter belongs inside a <shape>"),
])
def test_bad_area_light_is_one_line_naming_file_and_element(tmp_path, old, new, message):
    text = XML.replace("FLIP", "")
    assert old in text
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(SceneError) as e:
        _load(bad)
    line = str(e.value)
    assert line.startswith(f"{bad}:") and line.split(":")[1].isdigit(), line
    assert message in line and "\n" not in line, line
