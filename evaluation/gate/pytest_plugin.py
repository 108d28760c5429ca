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

Selection is pytest's own: ``pytest my_scenes/quad.toml`` runs that file's cases only (a
``.toml`` named on the command line is collected even without ``--whitted-scenes``), a node
id as ``pytest -v`` prints it (``my_scenes/quad.toml::oblique-classic-exact``) runs that one
case, and ``-k`` matches file and case names.

A case that fails with both images (FAIL, SIZE) writes them to the results folder
(``--whitted-results DIR`` or ini ``whitted_results``, default ``out/whitted-results`` of
the folder pytest was started in), one folder per case,
``<scene file without .toml>/<view>-<shading>-<mode>/``: ``ours``, ``golden`` and ``diff``
as EXR (linear, with their metadata) and PNG, and ``rule.png`` (the exact rule's verdict
drawn on the golden; ``evaluation.gate.artifacts``); the failure report lists their paths
and the metadata fields that differ. A case that passes writes nothing and removes those
files of an earlier failure.

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

_OPTIONS = ("scenes", "goldens", "backend", "results")
#: The results folder when neither the command line nor the ini file names one.
DEFAULT_RESULTS = Path("out") / "whitted-results"


def pytest_addoption(parser):
    group = parser.getgroup("whitted", "whitted golden regression tests")
    group.addoption("--whitted-scenes", metavar="DIR",
                    help="folder of scene files (.toml): one test per view x shading x mode")
    group.addoption("--whitted-goldens", metavar="DIR",
                    help="golden store (searched before the bundled one)")
    group.addoption("--whitted-backend", metavar="NAME",
                    help="our renderer's backend: auto (default), cuda, llvm")
    group.addoption("--whitted-results", metavar="DIR",
                    help="where a failing case writes ours, the golden and their difference "
                         f"(EXR + PNG; default {DEFAULT_RESULTS}/)")
    parser.addini("whitted_scenes", "folder of scene files for whitted golden tests")
    parser.addini("whitted_goldens", "golden store for whitted golden tests")
    parser.addini("whitted_backend", "backend of our renderer (auto, cuda, llvm)")
    parser.addini("whitted_results", "folder for the images of failing whitted cases")


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
        # the folder is collected unless an argument already covers it (the folder, a path
        # inside it such as one scene file or node id, or a folder above it)
        args = [Path(a.split("::")[0]).resolve() for a in config.args]
        if not any(folder == a or folder in a.parents or a in folder.parents for a in args):
            config.args.append(str(folder))
    results = _option(config, "results")
    config._whitted_results = (Path(results) if results else
                               Path(config.invocation_params.dir) / DEFAULT_RESULTS)


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
    results: Path | None = None      # results folder for a failure's images (None: none)

    @property
    def id(self) -> str:
        return f"{self.scene.stem}-{self.view_name}-{self.shading}-{self.mode}"

    @property
    def name(self) -> str:
        """The case's name within its scene file: ``<view>-<shading>-<mode>``."""
        return f"{self.view_name}-{self.shading}-{self.mode}"

    def verdict(self, keep_images: bool = False):
        from evaluation.gate.verdict import check_scene
        from reference.golden import search_stores

        found = check_scene(self.scene, search_stores(self.goldens), modes=[self.mode],
                            shadings=[self.shading], views={self.view},
                            backend=self.backend, keep_images=keep_images)
        return found[0]

    def images_folder(self) -> Path | None:
        """This case's folder under ``results``: ``<scene path without .toml, relative to
        the working folder when inside it>/<name>``."""
        if self.results is None:
            return None
        scene = self.scene.resolve().with_suffix("")
        try:
            rel = scene.relative_to(Path.cwd().resolve())
        except ValueError:
            rel = Path(scene.name)
        return Path(self.results) / rel / self.name

    def check(self):
        """Run the case; fail the test unless the verdict is PASS or WARN (a failure writes
        its images to the results folder and names them). Returns the verdict."""
        return assert_verdict(self.verdict(keep_images=self.results is not None),
                              self.images_folder())


class WhittedVerdictError(AssertionError):
    """A verdict other than PASS / WARN."""


def assert_verdict(v, images: Path | None = None):
    """``v`` if PASS (or WARN, with a warning); otherwise ``WhittedVerdictError`` with its
    verdict line, the metadata fields that differ and, where ``images`` names a folder and
    ``v`` kept both images, the paths of the images written there
    (``evaluation.gate.artifacts``). A PASS / WARN clears that folder's images."""
    from evaluation.gate.artifacts import clear_case_images, write_case_images
    from evaluation.gate.imagemeta import format_differences
    from evaluation.gate.verdict import format_line

    if v.status in ("PASS", "WARN"):
        if images is not None:
            clear_case_images(images)
        if v.status == "WARN":
            warnings.warn(format_line(v), stacklevel=3)
        return v
    lines = [format_line(v)]
    if v.differences:
        lines.append(format_differences(v.differences))
    if images is not None and v.ours is not None and v.ref is not None:
        try:
            written = write_case_images(images, v)
        except OSError as e:
            lines.append(f"        images not written: {e}")
        else:
            lines.append("        images (ours, the golden, |ours - golden|):")
            lines += [f"          {path}" for path in written.values()]
    raise WhittedVerdictError("\n".join(lines))


def cases_of(scene_path, *, goldens=None, modes=None, shadings=None,
             backend: str = "auto", results: Path | None = None) -> list[WhittedCase]:
    """Every case of one scene file (``evaluation.gate.verdict.plan_for``); ``results``:
    where a failing case writes its images. Raises SceneError."""
    from evaluation.gate.verdict import plan_for
    from renderer.scene import load_scene

    path = Path(scene_path)
    scene = load_scene(path)
    modes, shadings = plan_for(scene, modes, shadings)
    return [WhittedCase(path, v, cam.name, sh, m, goldens, backend, results)
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
        cases += cases_of(s, goldens=goldens, backend=backend,
                          results=getattr(config, "_whitted_results", None), **kw)
    def marks(c):
        key = c.id if c.id in xfail else c.scene.stem
        return [pytest.mark.xfail(strict=True, reason=xfail[key])] if key in xfail else []

    params = [pytest.param(c, marks=marks(c), id=c.id) for c in cases]
    metafunc.parametrize("whitted_case", params)


# ---- collecting a folder of scenes ----------------------------------------------------------
def pytest_collect_file(file_path: Path, parent):
    """A ``.toml`` under the scenes folder, or one named on the command line, is a scene
    file of tests."""
    if file_path.suffix != ".toml":
        return None
    folder = getattr(parent.config, "_whitted_scenes", None)
    inside = folder is not None and folder in file_path.resolve().parents
    if inside or parent.session.isinitpath(file_path):
        return WhittedSceneFile.from_parent(parent, path=file_path)
    return None


class WhittedSceneFile(pytest.File):
    """A scene file: one ``WhittedItem`` per case."""

    def collect(self):
        from renderer.scene import SceneError

        config = self.config
        try:
            cases = cases_of(self.path, goldens=_option(config, "goldens"),
                             backend=_option(config, "backend") or "auto",
                             results=config._whitted_results)
        except SceneError as e:
            yield WhittedItem.from_parent(self, name="load", case=None, error=str(e))
            return
        for c in cases:
            yield WhittedItem.from_parent(self, name=c.name, case=c)


class WhittedItem(pytest.Item):
    """One golden case; its outcome is the verdict's."""

    def __init__(self, *, case, error: str | None = None, **kw):
        super().__init__(**kw)
        self.case = case
        self.error = error

    def runtest(self):
        if self.error is not None:
            raise WhittedVerdictError(f"ERROR   {self.path.name}: {self.error}")
        v = self.case.verdict(keep_images=True)
        self.user_properties += [("verdict", v.status), ("reason", v.reason)]
        self.user_properties += [(f"excused {k}", str(n)) for k, n in v.excused.items()]
        assert_verdict(v, self.case.images_folder())

    def repr_failure(self, excinfo):
        if isinstance(excinfo.value, WhittedVerdictError):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self):
        # the domain is the failure section's title; one that is not the end of the node id
        # keeps ``pytest -v``'s line the node id itself (pytest rewrites a matching
        # domain's dots as "::"), so the line can be pasted back as an argument
        return self.path, None, f"{self.name} ({self.path.name})"
