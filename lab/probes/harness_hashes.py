import hashlib, json, sys, warnings
warnings.simplefilter("ignore")
from pathlib import Path
root = Path(sys.argv[1]); out = sys.argv[2]
sys.path.insert(0, str(root))
import numpy as np
from renderer.scene import load_scene
from reference.mitsuba_scene import render_mitsuba
res = {}
for name in ["analytic_quad", "bunny", "cornell_box", "cornell_sphere", "glass_bunny",
             "platonic_solids", "cases/fresnel_glass", "cases/mirror_background", "sponza", "conference"]:
    for shading in ("classic", "physical"):
        sc = load_scene(root / "scenes" / f"{name}.toml", shading=shading).with_size(48, 48)
        for v, cam in enumerate(sc.cameras):
            for mode, spp in (("exact", 1), ("converged", 4)):
                img = render_mitsuba(sc, view=v, mode=mode, spp=spp)
                k = f"{name}/{cam.name}/{shading}/{mode}"
                res[k] = hashlib.sha256(np.ascontiguousarray(np.asarray(img, np.float32)).tobytes()).hexdigest()
                print(k, res[k][:12], flush=True)
json.dump(res, open(out, "w"), indent=1)
