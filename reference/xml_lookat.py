"""An exported Mitsuba XML file whose sensor is written as the view's own ``<lookat>``.

``export_xml`` (``mitsuba_scene``) writes the sensor's ``to_world`` as the float32 matrix of
``ScalarTransform4f.look_at``; Mitsuba builds the same matrix from a ``<lookat>`` of the
view's position, target and up, and a reader of the file (``renderer.scene.load_scene``)
gets the view back exactly, so an export read back renders the same image bit for bit.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from renderer.outputs import write_text
from renderer.scene import Camera


def _triple(v) -> str:
    return ", ".join(repr(float(x)) for x in v)


def write_lookat(xml: Path, camera: Camera) -> None:
    """Replace the sensor's ``to_world`` in the XML file ``xml`` by ``<lookat origin target
    up>`` of ``camera`` (float64 values written exactly); the file is rewritten
    atomically."""
    xml = Path(xml)
    root = ET.fromstring(xml.read_text(encoding="utf-8"))
    for tr in root.iterfind("sensor/transform[@name='to_world']"):
        for child in list(tr):
            tr.remove(child)
        ET.SubElement(tr, "lookat", origin=_triple(camera.position),
                      target=_triple(camera.target), up=_triple(camera.up))
    ET.indent(root)
    write_text(xml, ET.tostring(root, encoding="unicode") + "\n", overwrite=True,
               flag="--force")
