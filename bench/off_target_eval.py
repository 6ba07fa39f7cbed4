"""How sharp the capture's off-target flag is (docs/app.md, "Touch quality").

Simulated 20-touch sessions on the paper's cone (the app's simulated skin): touches in turn
get the image of a press at a surface point ``d`` mm from their target (the finger went
there instead), and the share of such touches flagged, and of the other touches flagged with
it, is counted. Clean sessions and the real recordings (every touch taken as good, real
probing noise) give the false flags. On the real recordings, where no new image can be
made, 20 touches in turn keep their image and have their target moved ``d`` mm instead (the
same mismatch, but the wrong target, not the image, lies among the other touches).

    python bench/off_target_eval.py [--sessions 10] [--limit 4.0]
        [--data ../shared/data/hiro-cone-skin]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from skinloc.app.capture import off_target
from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.data.recording import read_recording
from skinloc.geometry.mesh import cone_skin, load_mesh, surface_points
from skinloc.sim.skin import SimulatedSkin

DISTANCES_MM = (40.0, 70.0, 100.0)
REAL = (
    "ConeSkinData_RND_20PL_1.mat",
    "ConeSkinData_RND_20PL_2.mat",
    "ConeSkinData30Points_RND_30PL_1.mat",
    "ConeSkinData_RND_40PL_1.mat",
    "ConeSkinData50Points_RND_50PL_1.mat",
    "ConeSkinData80Points_RND_80PL_1.mat",
)


def displaced(surface: np.ndarray, target: np.ndarray, d_mm: float, rng) -> np.ndarray:
    """A surface point about ``d_mm`` from ``target`` (within 3 mm), m."""
    dist = 1e3 * np.linalg.norm(surface - target, axis=1)
    near = np.flatnonzero(np.abs(dist - d_mm) < 3.0)
    if len(near) == 0:
        return surface[int(np.argmin(np.abs(dist - d_mm)))]
    return surface[rng.choice(near)]


def pressed_image(skin: SimulatedSkin, point: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Mean image of a 10-frame press at ``point (3,)`` m, baseline subtracted, counts."""
    skin.press(point, weak=False)
    frames, _ = skin.read_many(10)
    skin.release()
    return frames.mean(axis=0) - baseline


def score(targets, means, surface, rng, per_session: int, limit: float, skin=None):
    """Flags of the clean session, and of ``per_session`` touches off by each distance.

    With the simulated ``skin`` the touch's image is of a press off its target; without, its
    target is moved instead.
    """
    baseline = None
    if skin is not None:
        skin.connect()
        baseline = skin.read_many(50)[0].mean(axis=0)
    out: dict[str, list] = {"clean": [], "time": []}
    t0 = time.perf_counter()
    flags, _ = off_target(targets, means, limit=limit)
    out["time"].append(time.perf_counter() - t0)
    out["clean"].append(int(flags.sum()))
    for d in DISTANCES_MM:
        hit, other = [], []
        for j in rng.choice(len(targets), per_session, replace=False):
            moved, images = targets.copy(), means.copy()
            elsewhere = displaced(surface, targets[j], d, rng)
            if skin is None:
                moved[j] = elsewhere
            else:
                images[j] = pressed_image(skin, elsewhere, baseline)
            flags, _ = off_target(moved, images, limit=limit)
            hit.append(bool(flags[j]))
            other.append(int(flags.sum() - flags[j]))
        out[f"hit{d:.0f}"] = hit
        out[f"other{d:.0f}"] = other
    if skin is not None:
        skin.disconnect()
    return out


def report(name: str, res: dict[str, list], n_touches: int) -> None:
    clean = np.asarray(res["clean"])
    print(
        f"{name}: clean sessions {len(clean)}, false flags {clean.sum()} of "
        f"{len(clean) * n_touches} touches; check {1e3 * np.median(res['time']):.0f} ms"
    )
    for d in DISTANCES_MM:
        hit, other = np.asarray(res[f"hit{d:.0f}"]), np.asarray(res[f"other{d:.0f}"])
        print(
            f"  touch {d:.0f} mm off: flagged {hit.mean():.0%} ({hit.sum()}/{len(hit)}), "
            f"good touches flagged with it {other.sum()} of {len(other) * (n_touches - 1)}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--per-session", type=int, default=6)
    ap.add_argument("--limit", type=float, default=4.0, help="off_target's limit")
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    mesh = cone_skin()
    surface = surface_points(mesh, 2000)
    res: dict[str, list] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for s in range(args.sessions):
            skin = SimulatedSkin(mesh, random_state=100 + s)
            cfg = SessionConfig(n_points=20, samples_per_touch=10, random_state=s)
            rec = simulate_session(skin, mesh, Path(tmp) / f"s{s}.h5", cfg)
            for how, sim in (("pressed", skin), ("moved", None)):
                one = score(
                    rec.targets, rec.touch_means, surface, rng, args.per_session, args.limit, sim
                )
                for k, v in one.items():
                    res.setdefault((how, k), []).extend(v)
    for how, what in (("pressed", "pressed d mm off"), ("moved", "target moved d mm")):
        part = {k: v for (h, k), v in res.items() if h == how}
        report(f"simulated 20 touches, {what}", part, 20)
    if not args.data.is_dir():
        print(f"no real recordings at {args.data}: skipped")
        return
    real_surface = surface_points(load_mesh(args.data / "Color_Cone.obj"), 2000)
    for name in REAL:
        rec = read_recording(args.data / name)
        n_moved = min(rec.n_point_logs, 20)
        one = score(rec.targets, rec.touch_means, real_surface, rng, n_moved, args.limit)
        report(f"real {name} ({rec.n_point_logs} touches), target moved", one, rec.n_point_logs)


if __name__ == "__main__":
    main()
