"""The real recordings of 2023-12-10 (one session of the paper's skin), for the bench scripts.

Shared by ``coverage_eval.py``, ``label_noise.py``, ``active_eval.py`` and
``sensor_map_eval.py``: the file names, the ``--data`` option and their loading.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from skinloc.bench.paper import REAL_DEC
from skinloc.data.recording import Recording, read_recording

#: The four recordings of 2023-12-10, in recording order.
DAY: list[str] = list(REAL_DEC)
DEFAULT_DATA = Path("../shared/data/hiro-cone-skin")


def day_parser(doc: str | None) -> argparse.ArgumentParser:
    """An argument parser described by the script's first docstring line, with ``--data``."""
    ap = argparse.ArgumentParser(description=(doc or "").splitlines()[0] if doc else None)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    return ap


def have_day(data: Path) -> bool:
    """Whether ``data`` holds the recordings of 2023-12-10."""
    return all((data / name).is_file() for name in DAY)


def load_day(data: Path) -> dict[str, Recording]:
    """The recordings of 2023-12-10 by file name; exits with one line if any is missing."""
    missing = [name for name in DAY if not (data / name).is_file()]
    if missing:
        sys.exit(f"error: {data} lacks {', '.join(missing)} (give --data)")
    return {name: read_recording(data / name) for name in DAY}
