"""Map previews for the ground: a 2-D map array -> a small JPEG for MAVLink image transfer.

Topic contract (``[mavlink] map_preview_topic``, default ``map.updated``, the perception
task's map updates): a 2-D numpy array in map orientation (index ``[iy, ix]``, row 0 = lowest
y; fsw/core/geometry.py), either float elevation in metres with NaN where unknown, or a uint8
image; or an object with such an array as ``z`` (an ``ElevationMap``); or an object with an
``ElevationMap`` as ``snapshot`` (a ``MapUpdate``). The preview is flipped
so that +y (the world's "north") is up, scaled so its longest side is at most ``max_px``,
elevations stretched to 16..255 over the known cells (0 = unknown; the ground reads < 8 as
unknown, so JPEG noise does not turn low ground into holes), and JPEG encoded.

An elevation map (an ``ElevationMap`` or a ``MapUpdate``'s snapshot) is previewed as the team
link would carry it: :func:`reduce_map` runs the map codec (docs/algorithm.md §6: the quadtree of
interest regions within the codec's error bound, ``fsw.core.codec.mapcodec``) and previews its
decode, so the operator sees the map the Cliff-bot receives, not the raw fusion grid.
"""

from __future__ import annotations

import cv2
import numpy as np

from fsw.core.codec.mapcodec import CodecConfig, decode_map, encode_map
from fsw.core.map.elevation_map import ElevationMap

KNOWN_MIN = 16  # known elevations span 16..255, unknown is 0: the gap survives JPEG noise
UNKNOWN_BELOW = 8  # the ground reads grey levels below this as unknown


class PreviewError(ValueError):
    """The published object cannot be turned into a preview."""


def reduce_map(obj: object, *, wheel_diameter_m: float, codec: CodecConfig) -> tuple[object, int]:
    """``(preview_source, container_bytes)``: an elevation map becomes the codec's decode of it
    (float32, NaN unknown) and the size of the codec's container; any other object is returned
    as it is, with 0 bytes. Raises :class:`PreviewError` when the codec refuses the map."""
    snapshot = getattr(obj, "snapshot", None)
    emap = snapshot if isinstance(snapshot, ElevationMap) else obj
    if not isinstance(emap, ElevationMap):
        return obj, 0
    z = np.asarray(emap.z, np.float32)
    if not np.isfinite(z).any():
        return z, 0  # nothing mapped yet: nothing to reduce
    try:
        enc = encode_map(z, cell_m=float(emap.grid.cell), wheel_diameter_m=wheel_diameter_m, cfg=codec)
        return decode_map(enc.data, max_cells=codec.max_cells).z, len(enc.data)
    except ValueError as exc:  # MapCodecError is a ValueError
        raise PreviewError(f"map codec: {exc}") from exc


def encode_preview(obj: object, max_px: int, quality: int) -> tuple[bytes, int, int]:
    """``(jpeg_bytes, width, height)``; raises :class:`PreviewError` with the reason."""
    snapshot = getattr(obj, "snapshot", None)
    if isinstance(snapshot, ElevationMap):
        obj = snapshot
    if isinstance(obj, ElevationMap):
        obj = obj.z
    arr = np.asarray(obj)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise PreviewError(f"expected a 2-D array, got shape {arr.shape}")
    if arr.dtype == np.uint8:
        img = arr
    elif arr.dtype.kind in "fiu":
        z = arr.astype(np.float64)
        known = np.isfinite(z)
        img = np.zeros(z.shape, np.uint8)
        if known.any():
            lo, hi = float(z[known].min()), float(z[known].max())
            span = hi - lo if hi > lo else 1.0
            img[known] = (KNOWN_MIN + (255 - KNOWN_MIN) * (z[known] - lo) / span).round().astype(np.uint8)
    else:
        raise PreviewError(f"unsupported dtype {arr.dtype}")
    img = np.ascontiguousarray(img[::-1])
    h, w = img.shape
    scale = min(1.0, max_px / max(h, w))
    if scale < 1.0:
        w, h = max(1, round(w * scale)), max(1, round(h * scale))
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise PreviewError("JPEG encoding failed")
    return buf.tobytes(), w, h
