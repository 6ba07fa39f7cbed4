"""Soak test: read `skinloc virtual-skin --faults` through SerialSource for minutes.

Starts the virtual device as a separate process (so the host's memory is the reader's alone),
reads every frame with SerialSource, stops the device, then checks against the device's ground
truth that the frames delivered are exactly the frames sent intact (sent minus those the faults
destroyed), in order, counts wrong frames (delivered values the device never sent intact),
samples the reader's resident memory every 10 s, and counts disconnects and reconnects. Exits 1
if a frame is wrong, missing or out of order.

    python bench/soak.py --minutes 10 --format binary --rate 100 --out soak-binary.json
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from skinloc.errors import FrameTimeoutError
from skinloc.hardware.serial import SerialSource, SerialSourceConfig


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
    duration = args.minutes * 60
    # The soak's own bookkeeping is allocated (and its pages touched) up front, so the resident
    # memory sampled below grows only if the reader's does.
    cap = int(duration * args.rate * 1.2) + 10_000
    crcs = np.full(cap, 0, dtype=np.uint32)
    arrivals = np.full(cap, np.nan)
    n = 0
    rss: list[tuple[float, float]] = []
    stalls = 0
    t0 = time.monotonic()
    next_sample = t0
    while time.monotonic() - t0 < duration:
        try:
            f = src.read(timeout_s=2.0)
            crcs[n] = zlib.crc32(f.values.astype("<u2").tobytes())
            arrivals[n] = f.timestamp_s
            n += 1
        except FrameTimeoutError:
            stalls += 1
        now = time.monotonic()
        if now >= next_sample:
            rss.append((now - t0, rss_mb()))
            next_sample += 10.0
    dev.terminate()  # SIGTERM: the device drains, saves its ground truth and exits
    while n < cap:  # read what is still in flight
        try:
            f = src.read(timeout_s=1.0)
            crcs[n] = zlib.crc32(f.values.astype("<u2").tobytes())
            arrivals[n] = f.timestamp_s
            n += 1
        except FrameTimeoutError:
            break
    dev.wait(timeout=30)
    stats = src.stats()
    src.disconnect()
    dev_err = dev.stderr.read()

    with np.load(truth_path) as z:
        truth = {k: z[k] for k in z.files}
    shutil.rmtree(tmp, ignore_errors=True)
    fate = truth["fate"]
    sent_intact = truth["crc"][fate == 0]  # in the order the device wrote them
    delivered = crcs[:n]
    # A wrong frame is one whose values the device never sent intact (a CRC-32 of the values
    # is the fingerprint: a wrong frame matching an intact one has odds of 2^-32 per frame).
    is_wrong = ~np.isin(delivered, sent_intact)
    right = delivered[~is_wrong]
    found = re.findall(r"disconnects (\d+)", dev_err)
    n_disconnects = int(found[-1]) if found else -1
    gaps = np.diff(arrivals[:n]) if n > 1 else np.zeros(1)
    rss_arr = np.array(rss)
    after_1min = rss_arr[rss_arr[:, 0] >= 60] if len(rss_arr) else rss_arr
    slope = (
        float(np.polyfit(after_1min[:, 0] / 60, after_1min[:, 1], 1)[0])
        if len(after_1min) >= 3
        else None
    )
    result = {
        "command": " ".join(["python", "bench/soak.py", *sys.argv[1:]]),
        "format": args.format,
        "minutes": args.minutes,
        "rate_hz": args.rate,
        "frames_generated": int(len(fate)),
        "frames_sent_to_the_host": int((fate != 2).sum()),
        "frames_destroyed_by_faults": int((fate == 1).sum()),
        "frames_sent_intact": int(len(sent_intact)),
        "frames_unheard_while_unplugged": int((fate == 2).sum()),
        "frames_delivered": int(n),
        "wrong_frames": int(is_wrong.sum()),
        "right_frames_equal_sent_intact_in_order": bool(np.array_equal(right, sent_intact)),
        "intact_frames_not_delivered": int(len(sent_intact) - len(right)),
        "device_disconnects": n_disconnects,
        "host_disconnects_seen": stats.n_disconnects,
        "host_reconnects": stats.n_reconnects,
        # The device's own stop closes the port once more: the last loss is not recovered.
        "every_disconnect_recovered": stats.n_reconnects >= n_disconnects,
        "longest_gap_between_frames_s": round(float(gaps.max()), 3),
        "gaps_over_0.25s": int((gaps > 0.25).sum()),
        "read_timeouts_2s": stalls,
        "host_stats": stats.as_dict(),
        "rss_mb_at_1min_and_end": [float(after_1min[0, 1]), float(after_1min[-1, 1])]
        if len(after_1min)
        else None,
        "rss_mb_per_min_after_1min": slope,
        "rss_mb_samples": rss,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "device_summary": dev_err.strip().splitlines()[-1] if dev_err.strip() else "",
    }
    text = json.dumps(result, indent=2)
    if args.out:
        args.out.write_text(text)
    print(json.dumps({k: v for k, v in result.items() if k != "rss_mb_samples"}, indent=2))
    ok = result["right_frames_equal_sent_intact_in_order"] and result["wrong_frames"] == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
