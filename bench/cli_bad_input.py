"""Every ``skinloc`` command with bad input: exit code and the first line it prints.

Builds a folder of good and bad files (a small simulated recording and its model, empty,
truncated, foreign, NaN, wrong sensor count, degenerate meshes), runs each case as a
subprocess, checks that no file in the folder changed, and prints a Markdown table (the one at
bench/results/cli-bad-input.md; docs/reliability.md says what it checks).

    python bench/cli_bad_input.py > table.md

A case passes when it exits non-zero (or 0 where a warning is expected), prints no traceback,
and leaves every existing file as it was.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np

#: (command, what is wrong, argv with {dir} for the fixture folder, expected exit: None = non-zero)
CASES: list[tuple[str, str, str, int | None]] = [
    # demo
    ("demo", "--out in a missing folder", "demo --out {dir}/missing/demo", None),
    ("demo", "--out is a file", "demo --out {dir}/cal.h5", None),
    ("demo", "--points 1", "demo --points 1 --out {dir}/d", None),
    ("demo", "--seed -1", "demo --seed -1 --out {dir}/d", None),
    # simulate
    ("simulate", "--points 0", "simulate --points 0 --out {dir}/new.h5", None),
    ("simulate", "--points 100000000", "simulate --points 100000000 --out {dir}/new.h5", None),
    ("simulate", "--seed -1", "simulate --seed -1 --out {dir}/new.h5", None),
    ("simulate", "--tx 30", "simulate --tx 30 --out {dir}/new.h5", None),
    ("simulate", "--out exists (no --force)", "simulate --points 2 --out {dir}/cal.h5", None),
    ("simulate", "--out in a missing folder", "simulate --out {dir}/missing/x.h5", None),
    ("simulate", "--out in an unwritable folder", "simulate --out /proc/x.h5", None),
    ("simulate", "--out is a folder", "simulate --out {dir}", None),
    ("simulate", "--out x.txt", "simulate --out {dir}/x.txt", None),
    ("simulate", "--mesh missing", "simulate --mesh {dir}/nope.obj --out {dir}/new.h5", None),
    ("simulate", "--mesh is text", "simulate --mesh {dir}/text.obj --out {dir}/new.h5", None),
    ("simulate", "--mesh of zero area", "simulate --mesh {dir}/flat.obj --out {dir}/new.h5", None),
    ("simulate", "--mesh == --out", "simulate --mesh {dir}/cone.obj --out {dir}/cone.obj", None),
    # train
    ("train", "recording missing", "train {dir}/nope.h5 --out {dir}/m.h5", None),
    ("train", "recording is a folder", "train {dir} --out {dir}/m.h5", None),
    ("train", "recording empty", "train {dir}/empty.h5 --out {dir}/m.h5", None),
    ("train", "recording truncated", "train {dir}/truncated.h5 --out {dir}/m.h5", None),
    ("train", "recording is text", "train {dir}/text.h5 --out {dir}/m.h5", None),
    ("train", "recording is foreign HDF5", "train {dir}/foreign.h5 --out {dir}/m.h5", None),
    ("train", "recording has NaN frames", "train {dir}/nan.h5 --out {dir}/m.h5", None),
    ("train", "recording is a model", "train {dir}/model.h5 --out {dir}/m.h5", None),
    ("train", "recording truncated .mat", "train {dir}/truncated.mat --out {dir}/m.h5", None),
    ("train", "--out == the recording", "train {dir}/cal.h5 --out {dir}/cal.h5", None),
    (
        "train",
        "--out == the recording (other spelling)",
        "train {dir}/cal.h5 --out {dir}/./cal.h5",
        None,
    ),
    (
        "train",
        "--out == --init",
        "train {dir}/cal.h5 --init {dir}/model.h5 --out {dir}/model.h5",
        None,
    ),
    ("train", "--out exists (no --force)", "train {dir}/cal.h5 --out {dir}/val.h5", None),
    ("train", "--out in a missing folder", "train {dir}/cal.h5 --out {dir}/missing/m.h5", None),
    ("train", "--out in an unwritable folder", "train {dir}/cal.h5 --out /proc/m.h5", None),
    ("train", "mixed sensor counts", "train {dir}/cal.h5 {dir}/grid4.h5 --out {dir}/m.h5", None),
    ("train", "--epochs 0", "train {dir}/cal.h5 --epochs 0 --out {dir}/m.h5", None),
    ("train", "--seed -1", "train {dir}/cal.h5 --seed -1 --out {dir}/m.h5", None),
    ("train", "one point log (warns, trains)", "train {dir}/one.h5 --out {dir}/one-model.h5", 0),
    # evaluate
    ("evaluate", "model missing", "evaluate {dir}/nope.h5 {dir}/val.h5", None),
    ("evaluate", "model is a recording", "evaluate {dir}/cal.h5 {dir}/val.h5", None),
    ("evaluate", "model truncated", "evaluate {dir}/truncated.h5 {dir}/val.h5", None),
    (
        "evaluate",
        "recording of another sensor count",
        "evaluate {dir}/model.h5 {dir}/grid4.h5",
        None,
    ),
    ("evaluate", "recording has NaN frames", "evaluate {dir}/model.h5 {dir}/nan.h5", None),
    ("evaluate", "no recording", "evaluate {dir}/model.h5", None),
    # snr, info
    ("snr", "recording empty", "snr {dir}/empty.h5", None),
    ("snr", "recording foreign HDF5", "snr {dir}/foreign.h5", None),
    ("info", "a folder", "info {dir}", None),
    ("info", "missing", "info {dir}/nope.h5", None),
    ("info", "truncated", "info {dir}/truncated.h5", None),
    ("info", "NaN frames", "info {dir}/nan.h5", None),
    ("info", "a model", "info {dir}/model.h5", None),
    # convert
    ("convert", "DST == SRC", "convert {dir}/cal.h5 {dir}/cal.h5", None),
    ("convert", "DST exists (no --force)", "convert {dir}/cal.h5 {dir}/val.h5", None),
    ("convert", "DST x.txt", "convert {dir}/cal.h5 {dir}/x.txt", None),
    ("convert", "DST in an unwritable folder", "convert {dir}/cal.h5 /proc/x.mat", None),
    ("convert", "SRC truncated", "convert {dir}/truncated.h5 {dir}/x.mat", None),
    # bench
    ("bench", "--sizes abc", "bench --sizes abc --out {dir}/b", None),
    ("bench", "--sizes 1", "bench --sizes 1 --out {dir}/b", None),
    ("bench", "--seeds 0", "bench --seeds 0 --out {dir}/b", None),
    ("bench", "--real missing", "bench --no-sim --real {dir}/missing --out {dir}/b", None),
    ("bench", "--out in a missing folder", "bench --sizes 2 --out {dir}/missing/b", None),
    ("bench", "--out is a file", "bench --sizes 2 --out {dir}/cal.h5", None),
    # export
    ("export", "nothing to write", "export {dir}/model.h5", None),
    ("export", "model missing", "export {dir}/nope.h5 --onnx {dir}/m.onnx", None),
    ("export", "model is a recording", "export {dir}/cal.h5 --onnx {dir}/m.onnx", None),
    ("export", "--onnx == the model", "export {dir}/model.h5 --onnx {dir}/model.h5", None),
    (
        "export",
        "--c-header exists (no --force)",
        "export {dir}/model.h5 --c-header {dir}/text.h5",
        None,
    ),
    (
        "export",
        "--c-header of the default model",
        "export {dir}/model.h5 --c-header {dir}/m.h",
        None,
    ),
    ("export", "--onnx in an unwritable folder", "export {dir}/model.h5 --onnx /proc/m.onnx", None),
    # run
    ("run", "no --model", "run --source sim --duration 1", None),
    ("run", "--model missing", "run --model {dir}/nope.h5 --duration 1", None),
    ("run", "--model is a recording", "run --model {dir}/cal.h5 --duration 1", None),
    (
        "run",
        "--source recording missing",
        "run --model {dir}/model.h5 --source {dir}/nope.h5",
        None,
    ),
    (
        "run",
        "--source of another sensor count",
        "run --model {dir}/model.h5 --source {dir}/grid4.h5 --fast",
        None,
    ),
    ("run", "--sink jsonl:MODEL", "run --model {dir}/model.h5 --sink jsonl:{dir}/model.h5", None),
    (
        "run",
        "--sink nonsense",
        "run --model {dir}/model.h5 --source sim --sink nonsense --duration 1",
        None,
    ),
    ("run", "--duration -1", "run --model {dir}/model.h5 --source sim --duration -1", None),
    # hardware
    ("monitor", "no --port", "monitor --seconds 1", None),
    ("monitor", "--port missing", "monitor --port {dir}/ttyNOPE --seconds 1", None),
    ("monitor", "--port and --source sim", "monitor --port x --source sim --seconds 1", None),
    ("record", "--out x.txt", "record --source sim --out {dir}/x.txt", None),
    (
        "record",
        "--out exists (no --force)",
        "record --source sim --seconds 1 --out {dir}/cal.h5",
        None,
    ),
    ("record", "--seconds -1", "record --source sim --seconds -1 --out {dir}/r.h5", None),
    ("collect", "--out x.txt", "collect --source sim --out {dir}/x.txt", None),
    (
        "collect",
        "--new over a recording (no --force)",
        "collect --source sim --new --out {dir}/cal.h5",
        None,
    ),
    ("collect", "--out is a model (resume)", "collect --source sim --out {dir}/model.h5", None),
    (
        "collect",
        "--out is truncated (resume)",
        "collect --source sim --out {dir}/truncated.h5",
        None,
    ),
    ("collect", "--points 0", "collect --source sim --points 0 --out {dir}/c.h5", None),
    ("virtual-skin", "--rate 0", "virtual-skin --rate 0 --seconds 1", None),
    ("virtual-skin", "--truth x.txt", "virtual-skin --seconds 1 --truth {dir}/x.txt", None),
    ("virtual-skin", "--truth exists", "virtual-skin --seconds 1 --truth {dir}/truth.npz", None),
    # app
    ("app", "--port 0", "app --port 0 --no-browser", None),
    ("app", "--seed -1", "app --seed -1 --no-browser", None),
    ("app", "--format nonsense", "app --format nonsense --no-browser", None),
    ("app", "--mesh of zero area", "app --mesh {dir}/flat.obj --no-browser", None),
    ("app", "--data is a file", "app --data {dir}/cal.h5 --no-browser --port 1", None),
]


def _skinloc(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "200"}
    return subprocess.run(
        [sys.executable, "-m", "skinloc", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def make_fixtures(d: Path) -> None:
    """Good and bad files in ``d``."""
    from skinloc.data.recording import Recording, read_recording, write_mat, write_recording
    from skinloc.geometry.mesh import cone_skin

    def ok(args: str) -> None:
        res = _skinloc(args.split(), d)
        if res.returncode != 0:
            raise SystemExit(f"fixture failed: skinloc {args}\n{res.stderr}")

    ok("simulate --points 12 --samples 10 --seed 0 --out cal.h5")
    ok("simulate --points 6 --samples 10 --seed 1 --mode random --out val.h5")
    ok("train cal.h5 --out model.h5")
    rec = read_recording(d / "cal.h5")
    write_recording(rec.subset([0]), d / "one.h5")
    grid4 = Recording(
        **{
            **rec.__dict__,
            "n_tx": 4,
            "n_rx": 4,
            "baseline_frames": rec.baseline_frames[:, :16],
            "frames": rec.frames[:, :, :16],
        }
    )
    write_recording(grid4, d / "grid4.h5")
    (d / "empty.h5").write_bytes(b"")
    raw = (d / "cal.h5").read_bytes()
    (d / "truncated.h5").write_bytes(raw[: len(raw) // 3])
    (d / "text.h5").write_text("time,x,y\n0,1,2\n")
    with h5py.File(d / "foreign.h5", "w") as f:
        f["data"] = np.arange(10)
    write_mat(rec, d / "cal.mat")
    mat = (d / "cal.mat").read_bytes()
    (d / "truncated.mat").write_bytes(mat[: len(mat) // 3])
    write_recording(rec, d / "nan.h5")
    with h5py.File(d / "nan.h5", "a") as f:
        frames = f["point_logs/frames"]
        bad = frames[()]
        bad[0, 0, 0] = np.nan
        frames[...] = bad
    cone_skin().export(d / "cone.obj")
    (d / "text.obj").write_text("this is not a mesh\n")
    (d / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 0 0\nf 1 2 3\nf 2 3 4\n")
    np.savez_compressed(d / "truth.npz", x=np.zeros(3))


def _digest(d: Path) -> dict[str, str]:
    return {
        str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(d.rglob("*"))
        if p.is_file()
    }


def run_case(case: tuple[str, str, str, int | None], d: Path) -> dict:
    cmd, what, argv, expect = case
    args = argv.format(dir=d).split()
    try:
        res = _skinloc(args, d, timeout=120)
        out = (res.stderr.strip() or res.stdout.strip()).splitlines()
        first = out[0] if out else ""
        if res.returncode == 2:  # a usage error: its message sits in a box under the usage
            msgs = [ln.strip(" │|") for ln in out if "Invalid value" in ln or "Missing" in ln]
            first = msgs[0].strip() if msgs else first
        code: int | str = res.returncode
        traceback = "Traceback" in res.stderr or "Exception ignored" in res.stderr
    except subprocess.TimeoutExpired:
        first, code, traceback = "(still running after 120 s)", "timeout", False
    good = (
        not traceback
        and code != "timeout"
        and ((expect is None and code != 0) or (expect is not None and code == expect))
    )
    return dict(cmd=cmd, what=what, argv=argv, code=code, first=first, good=good)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="Cases run at once.")
    ap.add_argument("--only", help="Run only the cases of this command.")
    args = ap.parse_args()
    cases = [c for c in CASES if args.only is None or c[0] == args.only]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        make_fixtures(d)
        before = _digest(d)
        with ThreadPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(lambda c: run_case(c, d), cases))
        after = _digest(d)
    changed = sorted(k for k in before if after.get(k) != before[k])
    print("| command | bad input | exit | first line printed | ok |")
    print("|---|---|---|---|---|")
    for r in rows:
        first = r["first"].replace(str(d), "DIR").replace("|", "\\|")
        if len(first) > 160:
            first = first[:157] + "..."
        ok = "yes" if r["good"] else "NO"
        print(f"| `{r['cmd']}` | {r['what']} | {r['code']} | {first} | {ok} |")
    print()
    n_bad = sum(not r["good"] for r in rows)
    print(
        f"{len(rows)} cases, {len(rows) - n_bad} as intended; existing files changed: "
        + (", ".join(changed) if changed else "none")
        + "."
    )
    if n_bad or changed:
        sys.exit(1)


if __name__ == "__main__":
    main()
