"""Accelerators and triangle routines are chosen by name; unknown names fail with the
choices listed."""
import pytest
from accel_util import scene_from_arrays, soup

from renderer.accel import (
    ACCELERATORS,
    DEFAULT_ACCELS,
    ROUTINES,
    build_accelerator,
    default_accel,
    triangle_routine,
)
from renderer.device import types


def test_every_registered_accelerator_builds_by_name():
    t = types("llvm")
    V, faces = soup(50, seed=1)   # fixed seed: a reproducible soup
    sc = scene_from_arrays(V, faces)
    assert set(DEFAULT_ACCELS.values()) <= set(ACCELERATORS)
    for name, cls in ACCELERATORS.items():
        acc = build_accelerator(name, sc, t)
        assert type(acc) is cls
        assert acc.stats()["accel"] == name and acc.tris.count == 50


def test_unknown_names_list_the_choices():
    with pytest.raises(ValueError, match="backend: expected one of .*'llvm'"):
        default_accel("metal")
    t = types("llvm")
    sc = scene_from_arrays(*soup(4, seed=1))
    with pytest.raises(ValueError, match="accel: expected one of .*'bvh'"):
        build_accelerator("kdtree", sc, t)
    with pytest.raises(ValueError, match="intersection: expected one of .*'moller_trumbore'"):
        triangle_routine("plucker")
    with pytest.raises(ValueError, match="intersection"):
        build_accelerator("bvh", sc, t, intersection="plucker")
    assert triangle_routine("moller_trumbore") is ROUTINES["moller_trumbore"]
