"""Shrink the carried Mitsuba wheel in .whl/ (made by ../shared/tools/device-wheels.sh) to
the plugins the project loads (``reference/`` and the bench's peers), so the working tree
plus .whl fit the device tool's 64 MiB. Rewrites the wheel in place; run from the
repository root: ``python3 ci/device_wheel_slim.py``."""
import glob
import os
import re
import sys
import zipfile

KEEP = set("""twosided scene independent stratified multijitter ldsampler direct path diffuse
dielectric conductor plastic roughconductor roughdielectric sphere rectangle disk cube
cylinder ply obj serialized shapegroup instance point spot directional area constant envmap
perspective orthographic thinlens hdrfilm box gaussian tent rgb srgb uniform d65 regular
irregular bitmap""".split())

src = glob.glob(".whl/mitsuba-*.whl")
if not src:
    sys.exit("device_wheel_slim: no .whl/mitsuba-*.whl (run ../shared/tools/device-wheels.sh)")
tmp = src[0] + ".tmp"
with zipfile.ZipFile(src[0]) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED,
                                                     compresslevel=9) as zout:
    for item in zin.infolist():
        plugin = re.match(r"mitsuba/plugins/(.*)\.so$", item.filename)
        if plugin and plugin.group(1) not in KEEP or item.filename.startswith(
                "mitsuba/data/sunsky"):
            continue
        zout.writestr(item, zin.read(item.filename))
before = os.path.getsize(src[0])
os.replace(tmp, src[0])
print(f"{src[0]}: {before >> 10} KiB -> {os.path.getsize(src[0]) >> 10} KiB")
