"""PNG pictures of a bag's outputs: every map colour-mapped, with a colour bar that says
what the colours mean, beside the camera image it was computed from.

`depth-nodes eval --previews DIR` writes them for any bag: scored against the ground truth
when the bag has one (the error maps too), or, for a user's own recording, just the
disparities, depth images and confidence maps it holds. One sheet per frame,
``<stamp>_sheet.png``: a row per kind of map (disparity, error, depth, confidence), the
left image first on the top row, the maps of a row side by side over one shared range and
one colour bar at the row's end; pixels without a value are black (grey on an error map).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from depth_nodes.errors import BagError, ConfigError, DepthNodesError
from depth_nodes.ros.disparity import read_disparity
from depth_nodes.ros.image import to_rgb8
from depth_nodes.ros.transport import image_pixels
from depth_nodes.tools.bags.io import BagReader, header_stamp

Array = NDArray[Any]
DISPARITY = 'stereo_msgs/msg/DisparityImage'
IMAGE = 'sensor_msgs/msg/Image'
COMPRESSED = 'sensor_msgs/msg/CompressedImage'
#: Width of the colour bar, px.
BAR_WIDTH = 70
#: The left image a map is drawn beside, the first of these the bag has.
LEFT_IMAGES = ('/left/image_rect_color', '/left/image_rect', '/left/image_raw',
               '/left/image_raw/compressed')


@dataclass(frozen=True)
class MapView:
    """One map to draw: values, the range the colours span, the colour map, the unit."""

    name: str
    values: Array
    low: float
    high: float
    colormap: int = cv2.COLORMAP_TURBO
    unit: str = 'px'
    #: What the map is (disparity, depth, error, ...), shown after the name.
    kind: str = ''
    #: BGR of a pixel without a value: black, but grey on an error map, whose colour for
    #: no error is black.
    missing: tuple[int, int, int] = (0, 0, 0)


def colour(values: Array, low: float, high: float, colormap: int,
           missing: tuple[int, int, int] = (0, 0, 0)) -> Array:
    """``values`` in [low, high] through ``colormap``; non-finite pixels ``missing``."""
    span = max(high - low, 1e-9)
    finite = np.isfinite(values)
    scaled = np.clip((np.where(finite, values, low) - low) * (255.0 / span), 0, 255)
    img = cv2.applyColorMap(scaled.astype(np.uint8), colormap)
    img[~finite] = missing
    return np.asarray(img)


def colour_bar(height: int, view: MapView) -> Array:
    """A vertical bar of ``view``'s colours, high at the top, with five labelled ticks."""
    ramp = np.linspace(view.high, view.low, max(height, 2), dtype=np.float64)[:, None]
    bar = colour(np.repeat(ramp, 14, axis=1), view.low, view.high, view.colormap)
    out = np.full((height, BAR_WIDTH, 3), 255, np.uint8)
    out[:, 4:18] = bar
    for k in range(5):
        y = round(k * (height - 1) / 4)
        value = view.high - k * (view.high - view.low) / 4
        out[y, 18:24] = 0
        text = f'{value:.3g}'
        cv2.putText(out, text, (25, min(max(y + 4, 10), height - 3)),
                    cv2.FONT_HERSHEY_PLAIN, 0.8, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(out, view.unit, (25, height // 2 + 20 if height > 60 else height - 3),
                cv2.FONT_HERSHEY_PLAIN, 0.8, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def _bgr(image: Array | None, shape: tuple[int, int]) -> Array:
    """The camera image as 8-bit BGR of the map's size (grey when there is none)."""
    if image is None:
        return np.full((*shape, 3), 128, np.uint8)
    img = image
    if img.dtype != np.uint8:
        img = (img.astype(np.float64) / max(float(np.nanmax(img)), 1.0) * 255).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.shape[:2] != shape:
        img = cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return np.asarray(img)


#: The order of a sheet's rows, by the kind of map.
ROW_ORDER = ('disparity', 'error', 'depth', 'confidence')
#: Height of a panel's title strip, px.
TITLE_HEIGHT = 22


def sheet_rows(views: Iterable[MapView]) -> list[list[MapView]]:
    """The views grouped into a sheet's rows (see the module notes), each row over one
    range: the lowest ``low`` and the highest ``high`` of its maps."""
    groups: dict[str, list[MapView]] = {}
    for view in views:
        groups.setdefault(view.kind or view.name, []).append(view)
    order = sorted(groups, key=lambda k: ROW_ORDER.index(k) if k in ROW_ORDER else len(ROW_ORDER))
    rows = []
    for kind in order:
        group = groups[kind]
        low = min(v.low for v in group)
        high = max(v.high for v in group)
        rows.append([MapView(v.name, v.values, low, high, v.colormap, v.unit, v.kind,
                             v.missing) for v in group])
    return rows


def _titled(panel: Array, text: str) -> Array:
    title = np.full((TITLE_HEIGHT, panel.shape[1], 3), 255, np.uint8)
    cv2.putText(title, text, (4, 16), cv2.FONT_HERSHEY_PLAIN, 1.0, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([title, panel])


def sheet(image: Array | None, views: Iterable[MapView]) -> Array:
    """One frame's sheet (see the module notes), BGR."""
    rows = sheet_rows(views)
    if not rows:
        raise ConfigError('nothing to draw on the sheet')
    h, w = rows[0][0].values.shape[:2]
    drawn = []
    for n, row in enumerate(rows):
        first = _bgr(image, (h, w)) if n == 0 else np.full((h, w, 3), 255, np.uint8)
        panels = [_titled(first, 'left image' if n == 0 else '')]
        for view in row:
            values = view.values
            if values.shape[:2] != (h, w):
                values = cv2.resize(values.astype(np.float32), (w, h),
                                    interpolation=cv2.INTER_NEAREST)
            text = f'{view.name} ({view.kind})' if view.kind else view.name
            panels.append(_titled(colour(values, view.low, view.high, view.colormap,
                                         view.missing), text))
        panels.append(_titled(colour_bar(h, row[0]), row[0].kind))
        drawn.append(np.hstack(panels))
    width = max(r.shape[1] for r in drawn)
    return np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)),
                             constant_values=255) for r in drawn])


def scored_views(frame: dict[str, Array], maps: dict[str, Array],
                 threshold: float) -> list[MapView]:
    """The maps of a frame scored against ground truth (``frame``: disparities by name,
    ``'ground truth'`` among them; ``maps``: depths and confidences): every disparity over
    the ground-truth range, its error saturating at 2 ``threshold`` px, every depth over
    the ground-truth depth's range, every confidence over 0 - 1."""
    gt = frame['ground truth']
    top = float(np.nanmax(gt))
    views = []
    for name, disp in frame.items():
        views.append(MapView(name, disp, 0.0, top, kind='disparity'))
        if name != 'ground truth':
            views.append(MapView(name, np.abs(disp - gt), 0.0, 2 * threshold,
                                 cv2.COLORMAP_INFERNO, kind='error', missing=(160, 160, 160)))
    depth_top = float(np.nanmax(maps['depth_gt'])) if 'depth_gt' in maps else None
    for name, values in maps.items():
        if name == 'depth_gt' or name.endswith('/depth'):
            high = depth_top if depth_top is not None else float(np.nanmax(values))
            views.append(MapView(name, values, 0.0, high, unit='m', kind='depth'))
        else:
            views.append(MapView(name, values, 0.0, 1.0, cv2.COLORMAP_VIRIDIS, unit='',
                                 kind='confidence'))
    return views


def write_views(folder: Path, stamp: int, image: Array | None,
                views: Iterable[MapView]) -> list[Path]:
    """The frame's sheet as ``<stamp>_sheet.png`` (see the module notes); returns it."""
    path = folder / f'{stamp}_sheet.png'
    if not cv2.imwrite(str(path), sheet(image, views)):
        raise ConfigError(f'cannot write {path}')
    return [path]


def previews_folder(folder: Path) -> None:
    """Create the previews folder now, so a bad path fails before the work, in one line."""
    existing = next((a for a in (folder, *folder.parents) if a.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError(f'cannot write previews to {folder}: {existing} is a file')
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f'cannot write previews to {folder}: {exc.strerror}') from None


def depth_metres(pixels: Array, encoding: str) -> Array:
    """A depth image (REP 118: 32FC1 metres, or 16UC1 millimetres with 0 unknown) as
    float32 metres with NaN unknown."""
    if encoding == '16UC1':
        return np.where(pixels > 0, pixels.astype(np.float32) / 1000.0, np.nan).astype(
            np.float32)
    return np.asarray(pixels, np.float32)


def _robust_range(values: Array) -> tuple[float, float]:
    finite = values[np.isfinite(values)]
    if not finite.size:
        return 0.0, 1.0
    low, high = np.percentile(finite, [1, 99])
    return float(low), float(high) if high > low else float(low) + 1.0


def _views_of(topic: str, msg: Any) -> MapView | None:
    """The view of one output message, or None for an image that is not a map."""
    if type(msg).__name__ == 'DisparityImage':
        disparity = read_disparity(msg).disparity
        low, high = _robust_range(disparity)
        return MapView(topic, disparity, low, high, kind='disparity')
    pixels, encoding = image_pixels(msg)
    if topic.endswith('/confidence') and encoding == '32FC1':
        return MapView(topic, pixels, 0.0, 1.0, cv2.COLORMAP_VIRIDIS, unit='',
                       kind='confidence')
    if topic.endswith(('/depth', '/depth_gt')) and encoding in ('32FC1', '16UC1'):
        metres = depth_metres(pixels, encoding)
        finite = metres[np.isfinite(metres)]
        high = float(np.percentile(finite, 99)) if finite.size else 1.0
        return MapView(topic, metres, 0.0, max(high, 1e-3), unit='m', kind='depth')
    return None


#: A frame is drawn once the bag has moved this far past its stamp (ns): its maps come
#: within a pipeline latency of its image, in a processed bag and in a live recording.
PENDING_NS = 3_000_000_000


def bag_sheets(path: str | Path, *, max_frames: int | None = None
               ) -> Iterator[tuple[int, Array]]:
    """``(stamp, sheet)`` of the first ``max_frames`` stamps (None: all) of a bag's maps
    (disparities, depth images, confidence maps), in stamp order, read as a stream (a
    frame is drawn once the messages are :data:`PENDING_NS` past its stamp).

    Raises:
        BagError: Unreadable bag, or no map in it.
        ConfigError: ``max_frames`` < 1.
    """
    if max_frames is not None and max_frames < 1:
        raise ConfigError(f'--preview-frames must be at least 1, got {max_frames}')
    with BagReader(path) as reader:
        # left-view maps (a right-view disparity would not line up with the left image)
        maps = sorted(t for t, kind in reader.topics.items() if (
            kind == DISPARITY and not t.endswith('_right')) or (
            kind == IMAGE and t.endswith(('/depth', '/confidence', '/depth_gt'))))
        if not maps:
            raise BagError(f'{path} holds no disparity, depth or confidence topic to draw')
        images = {t for t, kind in reader.topics.items() if kind in (IMAGE, COMPRESSED)
                  and t.endswith(LEFT_IMAGES)}
        pending: dict[int, dict[str, Any]] = {}
        done: set[int] = set()
        for bag_msg in reader.messages([*maps, *images]):
            stamp = header_stamp(bag_msg.data)  # read before deserialising the pixels
            if stamp in done:
                continue
            if stamp not in pending:
                if max_frames is not None and len(done) + len(pending) >= max_frames:
                    continue
                pending[stamp] = {}
            pending[stamp][bag_msg.topic] = bag_msg.deserialize()
            while pending and min(pending) < stamp - PENDING_NS:
                oldest = min(pending)
                done.add(oldest)
                if (drawn := _sheet_of(pending.pop(oldest), maps)) is not None:
                    yield oldest, drawn
        for stamp in sorted(pending):
            if (drawn := _sheet_of(pending[stamp], maps)) is not None:
                yield stamp, drawn


def _sheet_of(frame: dict[str, Any], maps: list[str]) -> Array | None:
    views, image = [], None
    for topic in maps:
        if topic not in frame:
            continue
        try:
            view = _views_of(topic, frame[topic])
        except DepthNodesError:
            continue  # a damaged message: nothing to draw
        if view is None:
            continue
        views.append(view)
        image = image if image is not None else _left_image(frame, topic)
    return sheet(image, views) if views else None


def bag_previews(path: str | Path, folder: str | Path, *, max_frames: int = 10
                 ) -> list[Path]:
    """The sheets of the first ``max_frames`` stamps of a bag (:func:`bag_sheets`) as
    ``<stamp>_sheet.png`` in ``folder``.

    Raises:
        BagError: Unreadable bag, or no map in it.
        ConfigError: The folder cannot be written, or ``max_frames`` < 1.
    """
    if max_frames < 1:
        raise ConfigError(f'--preview-frames must be at least 1, got {max_frames}')
    out = Path(folder)
    previews_folder(out)
    written = []
    for stamp, drawn in bag_sheets(path, max_frames=max_frames):
        target = out / f'{stamp}_sheet.png'
        if not cv2.imwrite(str(target), drawn):
            raise ConfigError(f'cannot write {target}')
        written.append(target)
    return written


def _left_image(frame: dict[str, Any], topic: str) -> Array | None:
    """The left camera image of ``topic``'s namespace in this frame, if the bag has one."""
    ns = topic.rsplit('/', 1)[0]
    for suffix in LEFT_IMAGES:
        msg = frame.get(f'{ns}{suffix}')
        if msg is not None:
            try:
                return cv2.cvtColor(to_rgb8(*image_pixels(msg)), cv2.COLOR_RGB2BGR)
            except DepthNodesError:
                return None
    return None
