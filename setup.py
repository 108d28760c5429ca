"""Build step the pyproject.toml tables cannot say: the wheel carries the data the commands
need as package data, copied at build time from where the repository keeps it:

- ``scenes/`` (scene files, meshes and their terms) → ``whitted/bundled/scenes/``, where
  ``whitted.data.scenes_dir()`` finds it in an installed copy;
- ``reference/goldens/`` (EXR + JSON sidecars) → ``reference/goldens/``, where
  ``reference.golden`` reads it.

Copied, not declared as ``package-data``, because setuptools would take every golden
folder for a package. The repository keeps ``scenes/`` at its root, where tests, README
commands and golden sidecars name it; an editable install copies nothing (it reads the
tree)."""
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
#: (source folder in the repository, destination inside the wheel, file suffixes)
DATA = [("scenes", "whitted/bundled/scenes", (".toml", ".ply", ".md", ".txt")),
        ("reference/goldens", "reference/goldens", (".exr", ".json"))]


class BuildPyWithData(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        for src_dir, dst_dir, suffixes in DATA:
            for src in sorted((ROOT / src_dir).rglob("*")):
                if src.is_file() and src.suffix in suffixes:
                    out = Path(self.build_lib) / dst_dir / src.relative_to(ROOT / src_dir)
                    self.mkpath(str(out.parent))
                    self.copy_file(str(src), str(out))


setup(cmdclass={"build_py": BuildPyWithData})
