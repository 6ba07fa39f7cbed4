"""Soak test: read `skinloc virtual-skin --faults` through SerialSource for minutes.

Starts the virtual device as a separate process (so the host's memory is the reader's alone),
reads every frame with SerialSource, stops the device, then checks against the device's ground
truth that frames delivered == frames sent intact (sent minus those the faults destroyed),
counts wrong frames (delivered values that the device never sent intact), samples the reader's
resident memory, and counts disconnects and reconnects.

    python bench/soak.py --minutes 10 --format binary --rate 100 --out soak-binary.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from skinloc.errors import FrameTimeoutError
from skinloc.sources.serial import SerialSource, SerialSourceConfig


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        pages = int(fh.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--format", choices=["binary", "text"], default="binary")
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--disconnect-every", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="skinloc-soak-"))
    truth_path = tmp / "truth.npz"
    cmd = [
        sys.executable,
        "-m",
        "skinloc",
        "virtual-skin",
        "--format",
        args.format,
        "--rate",
        str(args.rate),
        "--faults",
        "--disconnect-every",
        str(args.disconnect_every),
        "--seed",
        str(args.seed),
        "--truth",
        str(truth_path),
    ]
    dev = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = dev.stdout.readline().strip()
    print(f"device pid {dev.pid} on {port}", flush=True)

    src = SerialSource(SerialSourceConfig(port, format="auto", buffer_frames=4096))
    src.connect()
    crcs: list[int] = []
    arrivals: list[float] = []
    rss: list[tuple[float, float]] = []
    stalls = 0
    t0 = time.monotonic()
    next_sample = t0
    duration = args.minutes * 60
    while time.monotonic() - t0 < duration:
        try:
            f = src.read(timeout_s=2.0)
            crcs.append(zlib.crc32(f.values.astype("<u2").tobytes()))
            arrivals.append(f.timestamp_s)
        except FrameTimeoutError:
            stalls += 1
        now = time.monotonic()
        if now >= next_sample:
            rss.append((now - t0, rss_mb()))
            next_sample += 10.0
    dev.terminate()  # SIGTERM: the device drains, saves its ground truth and exits
    while True:  # read what is still in flight
        try:
            f = src.read(timeout_s=1.0)
            crcs.append(zlib.crc32(f.values.astype("<u2").tobytes()))
        except FrameTimeoutError:
            break
    dev.wait(timeout=30)
    stats = src.stats()
    src.disconnect()
    dev_err = dev.stderr.read()

    truth = np.load(truth_path)
    fate = truth["fate"]
    sent_crc = truth["crc"][fate == 0]
    intact = set(sent_crc.tolist())
    delivered = np.asarray(crcs, dtype=np.uint32)
    wrong = int(sum(1 for c in crcs if c not in intact))
    # in-order check: the delivered intact frames appear in the order they were sent
    order = {c: k for k, c in enumerate(truth["crc"].tolist())}
    pos = [order[c] for c in crcs if c in intact]
    in_order = bool(np.all(np.diff(pos) > 0)) if len(pos) > 1 else True
    found = re.findall(r"disconnects (\d+)", dev_err)
    n_disconnects = int(found[-1]) if found else -1
    gaps = np.diff(np.asarray(arrivals)) if len(arrivals) > 1 else np.zeros(1)
    rss_arr = np.array(rss)
    warm = rss_arr[rss_arr[:, 0] >= 60] if len(rss_arr) and rss_arr[-1, 0] >= 120 else rss_arr
    result = {
        "command": " ".join(["python", "bench/soak.py", *sys.argv[1:]]),
        "format": args.format,
        "minutes": args.minutes,
        "rate_hz": args.rate,
        "frames_generated": int(len(fate)),
        "frames_sent_intact": int((fate == 0).sum()),
        "frames_destroyed_by_faults": int((fate == 1).sum()),
        "frames_unheard_while_unplugged": int((fate == 2).sum()),
        "frames_delivered": int(len(delivered)),
        "delivered_equals_sent_intact": int(len(delivered)) == int((fate == 0).sum()),
        "intact_frames_missing": int(len(intact - set(crcs))),
        "wrong_frames": wrong,
        "in_order": in_order,
        "device_disconnects": n_disconnects,
        "host_disconnects_seen": stats.n_disconnects,
        "host_reconnects": stats.n_reconnects,
        "every_disconnect_recovered": stats.n_reconnects
        >= n_disconnects - (0 if stats.link_up else 1),
        "link_up_at_end": stats.link_up,
        "longest_gap_between_frames_s": float(gaps.max()),
        "gaps_over_0.25s": int((gaps > 0.25).sum()),
        "read_timeouts_2s": stalls,
        "host_stats": stats.as_dict(),
        "rss_mb_first_last_max_after_1min": [
            float(rss_arr[0, 1]),
            float(rss_arr[-1, 1]),
            float(warm[:, 1].max()),
        ]
        if len(rss_arr)
        else None,
        "rss_mb_samples": rss,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "device_summary": dev_err.strip().splitlines()[-1] if dev_err.strip() else "",
    }
    text = json.dumps(result, indent=2)
    if args.out:
        args.out.write_text(text)
    print(json.dumps({k: v for k, v in result.items() if k != "rss_mb_samples"}, indent=2))
    ok = result["delivered_equals_sent_intact"] and wrong == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
