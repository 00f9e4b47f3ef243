"""A motion mark: the tool's position drawn as three rulers beside the visual timecode
(timecode.py), in the rows of the left image the page never shows, so that the page can
tell, in the decoded picture itself, the first frame in which the arm has moved
(bench.hand_to_eye, docs/hand-to-eye.md).

Ruler k (k = 0, 1, 2: the left camera's x right, y down, z forward) is a white bar on
black whose length is the tool's coordinate along that axis at ``M_PER_PX`` (0.1 mm)
per pixel, modulo ``LENGTH`` pixels (9.6 mm). It is drawn from the same joints the arm
is drawn with, so it moves when the drawn arm does, magnified: in the picture itself one
pixel is about 1.5 mm of the tool's motion (the PUMA's tool at qn 1.7 m from the left
camera, focal length 1109 px at 1280×720), 15 times the mark's 0.1 mm (31 times at
640×360); bench.hand_to_eye reports it as ``mark``.

Layout (full size; a layer ``scale`` times the size has it at that scale): the rulers
start at x = ``X0`` (after the timecode's black frame) and sit in rows
[6, 12), [14, 20), [22, 28) on black from row 4: all inside the 28 rows the page crops
(web/src/view/stereo.ts TIMECODE_ROWS). Each ruler is read on its rows 8+8k, 9+8k
(even, as a 4:2:0 frame's copy needs) by counting the pixels brighter than mid-grey.
"""

from __future__ import annotations

import numpy as np

M_PER_PX = 1e-4  # metres of the tool's motion per pixel of a ruler
LENGTH = 96  # pixels of a ruler: it wraps every LENGTH * M_PER_PX = 9.6 mm
X0 = 528  # first pixel of the rulers (the timecode's frame ends at x = 524)
TOP = 4  # the mark's black background, rows TOP..BOTTOM
BOTTOM = 28
RULER_ROWS = ((6, 12), (14, 20), (22, 28))  # each ruler's rows [start, end)
READ_ROWS = (8, 16, 24)  # the first of the two rows each ruler is read on
MIN_WIDTH = X0 + LENGTH + 4  # narrower eyes carry no mark


def lengths(position_m: np.ndarray) -> list[int]:
    """Each ruler's bar, in pixels (0 … LENGTH − 1), for a position (3, metres)."""
    return [int(np.floor(float(p) / M_PER_PX)) % LENGTH for p in position_m]


def draw(image: np.ndarray, position_m: np.ndarray) -> bool:
    """Draw the mark for ``position_m`` (the tool in the left camera's frame, metres)
    into the left image (H × W × 3, uint8) in place; False if the image is too narrow."""
    if image.shape[1] < MIN_WIDTH or image.shape[0] < BOTTOM:
        return False
    image[TOP:BOTTOM, X0 - 4 : X0 + LENGTH + 4] = 0
    for (y0, y1), n in zip(RULER_ROWS, lengths(position_m), strict=True):
        image[y0:y1, X0 : X0 + n] = 255
    return True


def read(image: np.ndarray, scale: float = 1.0) -> list[float] | None:
    """Each ruler's length (pixels at full size) as drawn in ``image`` (the left image or
    the side-by-side picture, ``scale`` times the size drawn into); None if too narrow."""
    x0, width = round(X0 * scale), round(LENGTH * scale)
    if image.shape[1] < x0 + width:
        return None
    out = []
    for row in READ_ROWS:
        y = round(row * scale)
        strip = image[y : y + 2, x0 : x0 + width].astype(np.float32)
        if strip.ndim == 3:
            strip = strip.mean(axis=2)
        out.append(float((strip > 128).sum()) / strip.shape[0] / scale)
    return out


def moved_px(before: list[float], after: list[float]) -> float:
    """The largest change of a ruler between two readings, in pixels, wrap-aware (a bar
    that wrapped from LENGTH − 1 to 0 moved one pixel)."""
    most = 0.0
    for a, b in zip(before, after, strict=True):
        d = (b - a) % LENGTH
        most = max(most, min(d, LENGTH - d))
    return most
