"""Accelerators survive Dr.Jit's rebuilds of their objects with every field.

Dr.Jit rebuilds a PyTree when it carries it through ``dr.copy`` or a loop's state. A
dataclass with a hand-written ``DRJIT_STRUCT`` came back with only the listed fields (a
second triangle routine silently became ``moller_trumbore``, ``types`` None, ``info``
empty); plain dataclasses come back whole. Each accelerator is built with a routine that is
NOT the default, registered for the test, and every field is compared after the trip.
"""
import dataclasses

import drjit as dr
import numpy as np
import pytest
from accel_util import random_rays, scene_from_arrays, soup

from renderer.accel import ACCELERATORS, triangle
from renderer.device import types

ROUTINE = "moller_trumbore_under_test"


@pytest.fixture
def calls(monkeypatch):
    """Register ``ROUTINE`` (Möller–Trumbore under another name) and count how often it is
    traced."""
    traced = []

    def routine(*args, **kwargs):
        traced.append(1)
        return triangle.moller_trumbore(*args, **kwargs)

    monkeypatch.setitem(triangle.ROUTINES, ROUTINE, routine)
    return traced


def assert_same(a, b, where="accel"):
    """Every field of ``a`` equals ``b``'s: same Python types, equal host values, Dr.Jit
    arrays of equal type and contents, recursing into dataclasses and dicts."""
    assert type(a) is type(b), where
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, type):                # e.g. the array types of ``Types``
        assert a is b, where
    elif dr.is_array_v(a):
        assert np.array_equal(np.asarray(a.numpy()), np.asarray(b.numpy())), where
    else:
        assert a == b, where


def build(name):
    t = types("llvm")
    V, faces = soup(200, seed=21)   # fixed seed: a reproducible soup
    return ACCELERATORS[name].build(scene_from_arrays(V, faces, n_objects=3), t,
                                    intersection=ROUTINE)


@pytest.mark.parametrize("name", sorted(ACCELERATORS))
def test_copy_keeps_every_field(name, calls):
    acc = build(name)
    assert acc.intersection == ROUTINE
    assert_same(dr.copy(acc), acc)


@pytest.mark.parametrize("mode", ["symbolic", "evaluated"])
@pytest.mark.parametrize("name", sorted(ACCELERATORS))
def test_while_loop_state_keeps_every_field(name, mode, calls):
    t = types("llvm")
    acc = build(name)
    _, back = dr.while_loop((dr.zeros(t.UInt32, 8), acc), lambda i, a: i < 3,
                            lambda i, a: (i + 1, a), mode=mode)
    assert_same(back, acc)


@dr.syntax
def carry(a, UInt32, mode):
    """``a`` after three iterations of a loop that reassigns it (so it is loop state)."""
    i = dr.zeros(UInt32, 8)
    while dr.hint(i < 3, mode=mode, exclude=[UInt32, mode]):
        a = dr.copy(a)
        i += 1
    return a


@pytest.mark.parametrize("mode", ["symbolic", "evaluated"])
@pytest.mark.parametrize("name", sorted(ACCELERATORS))
def test_syntax_loop_state_keeps_every_field(name, mode, calls):
    """An accelerator assigned inside a ``@dr.syntax`` loop is loop state; the query made
    with the rebuilt object after the loop traces the registered routine and gives the
    original object's hits."""
    t = types("llvm")
    acc = build(name)
    ray, active = random_rays(t, 256, seed=23)

    back = carry(acc, t.UInt32, mode)
    assert_same(back, acc)
    before = len(calls)
    h = back.intersect(ray, active)
    assert len(calls) > before               # the registered routine was traced
    ref = acc.intersect(ray, active)
    for k in ("found", "t", "u", "v", "prim"):
        assert np.array_equal(getattr(h, k).numpy(), getattr(ref, k).numpy()), k
