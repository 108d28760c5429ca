"""pytest plugin (entry point ``pytest11``, name ``whitted``): golden regression tests from a
folder of scenes, one test per scene file x view x shading x mode, judged as ``whitted check``
judges them (``evaluation.gate.verdict``), so ``pytest --junitxml`` gives any CI the verdicts.

Point it at your scenes and golden store on the command line or in the ini file::

    pytest --whitted-scenes my_scenes --whitted-goldens my_goldens --junitxml out.xml

    [tool.pytest.ini_options]        # or pytest.ini / tox.ini [pytest]
    whitted_scenes = "my_scenes"
    whitted_goldens = "my_goldens"
    whitted_backend = "llvm"         # default: auto (CUDA where present)

Every ``*.toml`` under the scenes folder becomes a test file whose tests are named
``<view>-<shading>-<mode>``; which modes and shadings come from the scene's ``[check]`` table
(else exact mode in both shadings). PASS passes, WARN passes with a warning, FAIL / SIZE fail,
MISSING / STALE / ERROR fail with the message that says how to render the golden. The golden
store falls back to ``$WHITTED_GOLDENS`` / ``[tool.whitted] goldens``; the bundled store is
always searched last.

From test code, a test that takes ``whitted_case`` is run once per case of the scenes named by
its ``@pytest.mark.whitted(scenes=[...], goldens=..., modes=..., shadings=..., xfail={stem or case
id: reason})`` marker (or of the configured folder; ``xfail`` marks a scene's cases as expected,
strictly, to fail); ``whitted_case.verdict()`` returns the ``Verdict`` and
``whitted_case.check()`` fails the test unless it is PASS or WARN.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest

_OPTIONS = ("scenes", "goldens", "backend")


def pytest_addoption(parser):
    group = parser.getgroup("whitted", "whitted golden regression tests")
    group.addoption("--whitted-scenes", metavar="DIR",
                    help="folder of scene files (.toml): one test per view x shading x mode")
    group.addoption("--whitted-goldens", metavar="DIR",
                    help="golden store (searched before the bundled one)")
    group.addoption("--whitted-backend", metavar="NAME",
                    help="our renderer's backend: auto (default), cuda, llvm")
    parser.addini("whitted_scenes", "folder of scene files for whitted golden tests")
    parser.addini("whitted_goldens", "golden store for whitted golden tests")
    parser.addini("whitted_backend", "backend of our renderer (auto, cuda, llvm)")


def _option(config, name: str) -> str | None:
    """The command line's ``--whitted-<name>``, else the ini's ``whitted_<name>`` (relative
    paths there are relative to the ini file's folder)."""
    value = config.getoption(f"--whitted-{name}")
    if value:
        return value
    value = config.getini(f"whitted_{name}")
    if value and name != "backend" and config.inipath is not None:
        return str(Path(config.inipath).parent / value)
    return value or None


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "whitted(scenes, goldens=None, modes=None, shadings=None): the scenes "
                   "whose golden cases parametrize a test's `whitted_case` argument")
    scenes = _option(config, "scenes")
    if scenes:
        folder = Path(scenes).resolve()
        if not folder.is_dir():
            raise pytest.UsageError(f"--whitted-scenes {scenes}: not a folder")
        config._whitted_scenes = folder
        args = [Path(a.split("::")[0]).resolve() for a in config.args]
        if not any(folder == a or a in folder.parents for a in args):
            config.args.append(str(folder))


# ---- cases ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class WhittedCase:
    """One scene view in one shading and mode, against a golden store."""

    scene: Path
    view: int
    view_name: str
    shading: str
    mode: str
    goldens: str | None = None
    backend: str = "auto"

    @property
    def id(self) -> str:
        return f"{self.scene.stem}-{self.view_name}-{self.shading}-{self.mode}"

    def verdict(self):
        from evaluation.gate.verdict import check_scene
        from reference.golden import search_stores

        found = check_scene(self.scene, search_stores(self.goldens), modes=[self.mode],
                            shadings=[self.shading], views={self.view},
                            backend=self.backend)
        return found[0]

    def check(self):
        """Run the case; fail the test unless the verdict is PASS or WARN. Returns it."""
        return assert_verdict(self.verdict())


class WhittedVerdictError(AssertionError):
    """A verdict other than PASS / WARN."""


def assert_verdict(v):
    from evaluation.gate.verdict import format_line

    if v.status == "WARN":
        warnings.warn(format_line(v), stacklevel=2)
    elif v.status != "PASS":
        raise WhittedVerdictError(format_line(v))
    return v


def cases_of(scene_path, *, goldens=None, modes=None, shadings=None,
             backend: str = "auto") -> list[WhittedCase]:
    """Every case of one scene file (``evaluation.gate.verdict.plan_for``). Raises SceneError."""
    from evaluation.gate.verdict import plan_for
    from renderer.scene import load_scene

    path = Path(scene_path)
    scene = load_scene(path)
    modes, shadings = plan_for(scene, modes, shadings)
    return [WhittedCase(path, v, cam.name, sh, m, goldens, backend)
            for sh in shadings for v, cam in enumerate(scene.cameras) for m in modes]


def pytest_generate_tests(metafunc):
    if "whitted_case" not in metafunc.fixturenames:
        return
    config = metafunc.config
    marker = metafunc.definition.get_closest_marker("whitted")
    kw = dict(marker.kwargs) if marker else {}
    scenes = kw.pop("scenes", None)
    xfail = kw.pop("xfail", {})
    goldens = kw.pop("goldens", None) or _option(config, "goldens")
    backend = kw.pop("backend", None) or _option(config, "backend") or "auto"
    if scenes is None:
        folder = getattr(config, "_whitted_scenes", None)
        scenes = sorted(folder.rglob("*.toml")) if folder else []
    cases = []
    for s in scenes:
        cases += cases_of(s, goldens=goldens, backend=backend, **kw)
    def marks(c):
        key = c.id if c.id in xfail else c.scene.stem
        return [pytest.mark.xfail(strict=True, reason=xfail[key])] if key in xfail else []

    params = [pytest.param(c, marks=marks(c), id=c.id) for c in cases]
    metafunc.parametrize("whitted_case", params)


# ---- collecting a folder of scenes ----------------------------------------------------------
def pytest_collect_file(file_path: Path, parent):
    folder = getattr(parent.config, "_whitted_scenes", None)
    if folder is not None and file_path.suffix == ".toml" and folder in file_path.parents:
        return WhittedSceneFile.from_parent(parent, path=file_path)
    return None


class WhittedSceneFile(pytest.File):
    """A scene file: one ``WhittedItem`` per case."""

    def collect(self):
        from renderer.scene import SceneError

        config = self.config
        try:
            cases = cases_of(self.path, goldens=_option(config, "goldens"),
                             backend=_option(config, "backend") or "auto")
        except SceneError as e:
            yield WhittedItem.from_parent(self, name="load", case=None, error=str(e))
            return
        for c in cases:
            yield WhittedItem.from_parent(self, name=f"{c.view_name}-{c.shading}-{c.mode}",
                                          case=c)


class WhittedItem(pytest.Item):
    """One golden case; its outcome is the verdict's."""

    def __init__(self, *, case, error: str | None = None, **kw):
        super().__init__(**kw)
        self.case = case
        self.error = error

    def runtest(self):
        if self.error is not None:
            raise WhittedVerdictError(f"ERROR   {self.path.name}: {self.error}")
        v = self.case.verdict()
        self.user_properties += [("verdict", v.status), ("reason", v.reason)]
        self.user_properties += [(f"excused {k}", str(n)) for k, n in v.excused.items()]
        assert_verdict(v)

    def repr_failure(self, excinfo):
        if isinstance(excinfo.value, WhittedVerdictError):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self):
        return self.path, None, f"{self.path.name}::{self.name}"
