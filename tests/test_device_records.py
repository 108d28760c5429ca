"""Device records (plain typed dataclasses, no ``DRJIT_STRUCT``) keep every field when Dr.Jit
rebuilds them: through ``dr.copy`` and as ``dr.while_loop`` state."""
from __future__ import annotations

import dataclasses

import drjit as dr
import numpy as np
import pytest
from util import glass_scene

from renderer.camera import camera_arrays
from renderer.device import types
from renderer.lights import sample_light, upload_lights
from renderer.render import Renderer
from renderer.shade import upload_materials


def _records(backend):
    sc = glass_scene()
    t = types(backend)
    r = Renderer(sc, backend=backend)
    return {"materials": upload_materials(sc, t), "lights": upload_lights(sc, t),
            "camera": camera_arrays(sc.cameras[0], t), "scene_arrays": r.arrays,
            "light_sample": sample_light(upload_lights(sc, t), t.UInt32(0),
                                         t.Array3f(0.1, 0.2, 0.3), t)}


def _same(a, b, where):
    assert type(a) is type(b), where
    if dataclasses.is_dataclass(a):
        assert not hasattr(type(a), "DRJIT_STRUCT"), where
        for f in dataclasses.fields(a):
            if f.name == "accel":      # each accelerator has its own round-trip test
                continue
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif dr.is_array_v(a):
        np.testing.assert_array_equal(np.asarray(a.numpy()), np.asarray(b.numpy()), where)
    else:
        assert a == b, where


@pytest.mark.parametrize("name", ["materials", "lights", "camera", "scene_arrays",
                                  "light_sample"])
def test_record_survives_copy_and_loop_state(backend, name):
    rec = _records(backend)[name]
    _same(rec, dr.copy(rec), name)
    t = types(backend)
    i = t.UInt32(0)

    def cond(i, rec):
        return i < 2

    def body(i, rec):
        return i + 1, rec

    _, out = dr.while_loop((i, rec), cond, body, mode="symbolic")
    _same(rec, out, name)
