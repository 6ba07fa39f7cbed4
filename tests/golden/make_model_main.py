"""Write small model files with skinloc as of main (commit 780f4d6) and their predictions."""

import numpy as np
import trimesh

from skinloc.geometry.mesh import surface_points
from skinloc.models.localizer import ContactLocalizer

rng = np.random.default_rng(0)
mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
pts = surface_points(mesh, 400, random_state=0)
sensors = rng.normal(0, 0.05, (16, 3))


def images(p):
    d = np.linalg.norm(p[:, None, :] - sensors[None], axis=2)
    return 300 * np.exp(-((d / 0.03) ** 2)) + rng.normal(0, 2, (len(p), 16))


y = pts[rng.choice(len(pts), 40, replace=False)]
X = images(y)
Xt = images(pts[rng.choice(len(pts), 20, replace=False)])
out = {"frames": Xt}
for arch, kw in [
    ("default", {}),
    ("paper", {"epochs": 30}),
    ("mlp", {"epochs": 10, "hidden": (8,), "n_members": 2}),
]:
    m = ContactLocalizer(arch=arch, **kw).fit(X, y, mesh=mesh, surface_points=pts)
    m.save(f"tests/golden/model_main_{arch}.h5")
    p = m.predict_full(Xt)
    out[f"{arch}_points"], out[f"{arch}_raw"], out[f"{arch}_uncertainty_mm"] = (
        p.points,
        p.raw,
        p.uncertainty_mm,
    )
np.savez("tests/golden/model_main_predictions.npz", **out)
