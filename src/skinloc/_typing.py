"""Shape aliases used in signatures; all geometry is in metres."""

from typing import TypeAlias

import numpy as np
import numpy.typing as npt

#: One sensor image, ``(n_tx * n_rx,)`` float32 counts, TX-major (sensor k is TX k // n_rx).
Frame: TypeAlias = npt.NDArray[np.float32]
#: A batch of sensor images, ``(n, n_tx * n_rx)``.
Frames: TypeAlias = npt.NDArray[np.float32]
#: Points in the mesh frame, ``(n, 3)`` float64 metres.
Points: TypeAlias = npt.NDArray[np.float64]
