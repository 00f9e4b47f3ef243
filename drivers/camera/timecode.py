"""A visual timecode: the capture time drawn as large black/white blocks in a corner
of the left image, robust to video compression, so that glass-to-glass latency can
be measured by decoding the picture that arrives.

Layout: a row of ``BITS`` blocks of ``BLOCK`` pixels, framed by a white guard row
and column; bit i is white for 1. The value is the capture time in units of 0.1 ms,
modulo 2**BITS (about 7 minutes before it wraps).
"""

from __future__ import annotations

import numpy as np

BITS = 32
BLOCK = 16  # pixels per block side
UNIT = 1e-4  # seconds per count
ORIGIN = (8, 8)  # top-left corner (x, y) of the first block
WRAP: int = 1 << BITS


def encode_time(t: float) -> int:
    return round(t / UNIT) % WRAP


def draw(image: np.ndarray, t: float) -> None:
    """Draw the code for time ``t`` into ``image`` (H × W × 3, uint8) in place."""
    value = encode_time(t)
    x0, y0 = ORIGIN
    image[y0 - 4 : y0 + BLOCK + 4, x0 - 4 : x0 + BITS * BLOCK + 4] = 0
    for i in range(BITS):
        if value >> (BITS - 1 - i) & 1:
            image[y0 : y0 + BLOCK, x0 + i * BLOCK : x0 + (i + 1) * BLOCK] = 255


def read(image: np.ndarray, scale: float = 1.0) -> int | None:
    """The counter drawn in ``image``, read from the centre of each block. ``scale``:
    the picture's size against the one drawn into (0.5 for the video's low layer)."""
    if scale != 1.0:
        import cv2

        image = cv2.resize(image, None, fx=1 / scale, fy=1 / scale, interpolation=cv2.INTER_LINEAR)
    x0, y0 = ORIGIN
    cy = y0 + BLOCK // 2
    if image.shape[0] <= cy or image.shape[1] <= x0 + BITS * BLOCK:
        return None
    gray = image[cy - 2 : cy + 3, x0 : x0 + BITS * BLOCK].astype(np.float32)
    if gray.ndim == 3:
        gray = gray.mean(axis=2)
    centres = gray.reshape(5, BITS, BLOCK)[:, :, BLOCK // 4 : 3 * BLOCK // 4].mean(axis=(0, 2))
    value = 0
    for level in centres:
        value = (value << 1) | int(level > 128)
    return value


def elapsed(code: int, now: float) -> float:
    """Seconds from the time encoded in ``code`` to ``now`` (same clock), wrap-aware."""
    delta = (encode_time(now) - code) % WRAP
    return float(delta * UNIT)
