"""A re-driven rollout as a short clip (MP4, and a GIF for places that cannot play video), one picture per control
step: the frame the network saw, a top-down view with the path so far and the safe set (a Gymnasium world: the
env's own render where it draws one), and strips of η2, mutual information, the warning tier and the command.

Drawn with OpenCV alone (a static background once, then a few lines per frame), so a clip of a few hundred steps
costs well under a second to draw; the GIF is the MP4's pictures at full size (640 px wide), in one fixed palette.
Steps are numbered as the records count them (from 0: a failure at `step` 26 is drawn on the picture saying step
26), the failure is marked from the picture where it happens, and a strip with nothing to show says why.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from uqdrive.replay.redrive import Redriver, Watched, check_against
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.failures import FailurePlacer, RolloutFailure, placer_for

WIDTH, HEIGHT = 640, 512
TITLE_H, VIEW_H, STRIP_H = 28, 300, 44
CAMERA = (8, TITLE_H + 40, 256, 192)  # x, y, w, h: the network's 64x48 frame, 4x
TOP_DOWN = (280, TITLE_H, 352, VIEW_H)
STRIP_LABELS = ("eta2", "MI", "warning tier", "steer command")  # OpenCV's fonts draw ASCII only
FOURCC = "mp4v"  # MPEG-4 part 2: what OpenCV's wheels write and read back everywhere (no H.264 encoder in them)
INK, GREY, PATH, CAR, BAD = (30, 30, 30), (190, 190, 190), (200, 90, 20), (20, 20, 220), (40, 40, 200)
BANNER = (215, 215, 255)  # the failure banner's pale red fill (BGR), a colour of the GIF's palette
FONT, SMALL, LARGE = cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0.55  # 0.5: capitals 11 px high, the smallest label drawn
LEGEND = (("path so far", PATH), ("car", CAR), ("road edges (safe set)", INK), ("route", GREY))
# Why a strip has no line: η2 is drawn only where a warning tier reads it (or a recording asks for it); MI needs
# draws of the decision, which a policy without them does not give
EMPTY_STRIP = {"eta2": "not drawn: no warning reads it in this run", "MI": "none: the policy gives no draws"}


def _gif_palette() -> Image.Image:
    """One palette for every GIF picture: 200 greys (the network's frame) and the drawing's colours beside a coarse
    colour cube (a Gymnasium env's render). Mapping to a fixed palette costs a third of choosing one per picture."""
    greys = [(int(v),) * 3 for v in np.linspace(0, 255, 200)]
    cube = [(r, g, b) for r in (0, 128, 255) for g in (0, 128, 255) for b in (0, 128, 255)]
    drawing = [colour[::-1] for colour in (INK, GREY, PATH, CAR, BAD, BANNER)]  # BGR → RGB
    colours = greys + drawing + cube
    palette = Image.new("P", (1, 1))
    palette.putpalette([c for rgb in colours + [(0, 0, 0)] * (256 - len(colours)) for c in rgb])
    return palette


_GIF_PALETTE = _gif_palette()


@dataclasses.dataclass(frozen=True)
class Clip:
    """The files of a clip (``gif`` None: drawn as MP4 only) and how many pictures each holds."""

    mp4: Path
    gif: Path | None
    frames: int


def write_clip(
    watched: Watched,
    title: str,
    placer: FailurePlacer,
    folder: str | Path,
    name: str,
    hz: float,
    gif: bool = True,
    failure: RolloutFailure | None = None,
) -> Clip:
    """``name``.mp4 (and ``name``.gif unless not ``gif``) in ``folder``: one picture per step of the re-driven
    rollout, at ``hz``; ``failure`` (its record's): marked from the step it happened at."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    pictures = list(_pictures(watched, title, placer, failure))
    mp4 = folder / f"{name}.mp4"
    writer = cv2.VideoWriter(str(mp4), cv2.VideoWriter_fourcc(*FOURCC), float(hz), (WIDTH, HEIGHT))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {mp4} with fourcc {FOURCC}")
    for picture in pictures:
        writer.write(picture)
    writer.release()
    return Clip(mp4, write_gif(pictures, folder / f"{name}.gif", hz) if gif else None, len(pictures))


def write_gif(pictures: Sequence[np.ndarray], path: Path, hz: float) -> Path:
    """BGR ``pictures`` as a looping GIF at full size (labels readable), in one fixed palette."""
    rgb = [cv2.cvtColor(p, cv2.COLOR_BGR2RGB) for p in pictures]
    small = [Image.fromarray(p).quantize(palette=_GIF_PALETTE, dither=Image.Dither.NONE) for p in rgb]
    small[0].save(path, save_all=True, append_images=small[1:], duration=round(1000 / hz), loop=0)
    return path


def gif_of(mp4: Path, path: Path) -> Path:
    """A clip's GIF from its MP4 (the stages draw MP4s only; a page that shows a few of them makes their GIFs)."""
    capture = cv2.VideoCapture(str(mp4))
    hz, pictures = capture.get(cv2.CAP_PROP_FPS) or 15.0, []
    while True:
        ok, picture = capture.read()
        if not ok:
            break
        pictures.append(picture)
    capture.release()
    if not pictures:
        raise ValueError(f"{mp4}: no picture OpenCV can read")
    return write_gif(pictures, path, hz)


def worst_clips(
    job: RolloutJob, failures: Sequence[RolloutFailure], title: str, folder: str | Path, name: str, count: int
) -> list[Clip]:
    """MP4 clips of the first ``count`` of ``failures`` (a cell's, worst first), each re-driven and checked against
    its record before it is drawn; one that differs is not drawn, with a warning (the record stays the cell's word).
    No GIF: a few of them are made where they are shown (`gif_of`), saving 40 % of the drawing of every clip."""
    if count == 0 or not failures:
        return []
    clips = []
    with Redriver(job) as driver:
        for failure in failures[:count]:
            watched = driver.drive(failure.index)
            differences = check_against(watched, False, failure.margin, failure)
            if differences:
                warnings.warn(
                    f"{name} seed {failure.seed} re-drove differently: {'; '.join(differences)}", stacklevel=2
                )
                continue
            seed_title = f"{title} - seed {failure.seed}"
            placer = placer_for(job, failure.index)
            clip = write_clip(
                watched, seed_title, placer, folder, f"{name}-seed{failure.seed}", job.control_hz, False, failure
            )
            clips.append(clip)
    return clips


def _pictures(watched: Watched, title: str, placer: FailurePlacer, failure: RolloutFailure | None = None):
    """Each step's picture (BGR uint8 [HEIGHT, WIDTH, 3]), numbered from 0 as the record counts steps."""
    r = watched.result
    series = _series(watched)
    to_pixel = _top_down_transform(r.x, r.y, placer)
    background = _background(title, series, placer, to_pixel)
    points = np.stack(to_pixel(np.asarray(r.x), np.asarray(r.y)), axis=1).astype(np.int32)
    steps = r.steps
    for k in range(steps):
        picture = background.copy()
        _camera(picture, watched.frames[k])
        view = watched.views[k]
        if view is not None:
            x, y, w, h = TOP_DOWN
            picture[y : y + h, x : x + w] = cv2.resize(cv2.cvtColor(view, cv2.COLOR_RGB2BGR), (w, h))
            cv2.putText(picture, "the env's own render", (x + 4, y + 16), FONT, SMALL, INK, 1, cv2.LINE_AA)
        else:
            cv2.polylines(picture, [points[: k + 1]], False, PATH, 2, cv2.LINE_AA)
            cv2.circle(picture, tuple(int(v) for v in points[k]), 5, CAR, -1, cv2.LINE_AA)
        _strips(picture, series, k, steps)
        cv2.putText(picture, f"step {k}/{steps - 1}", (WIDTH - 118, 19), FONT, SMALL, INK, 1, cv2.LINE_AA)
        if failure is not None and k >= failure.step:
            _mark_failure(picture, failure, points[min(failure.step, len(points) - 1)], view is None)
        yield picture


def _mark_failure(picture: np.ndarray, failure: RolloutFailure, where: np.ndarray, top_down: bool) -> None:
    """From the failing step on: what broke and when (the record's words), and a cross where it happened."""
    x, y, w, _ = TOP_DOWN
    text = f"FAILED at step {failure.step}: {failure.cause}"
    cv2.rectangle(picture, (x + 1, y + 22), (x + w - 2, y + 44), BANNER, -1)
    cv2.putText(picture, text[:36], (x + 6, y + 39), FONT, LARGE, BAD, 1, cv2.LINE_AA)
    if top_down:
        cx, cy = (int(v) for v in where)
        cv2.line(picture, (cx - 8, cy - 8), (cx + 8, cy + 8), BAD, 2, cv2.LINE_AA)
        cv2.line(picture, (cx - 8, cy + 8), (cx + 8, cy - 8), BAD, 2, cv2.LINE_AA)


def _series(watched: Watched) -> list[tuple[np.ndarray, float, float]]:
    """Each strip's values per step and its range: η2 in [0, 1], MI from 0, tier in [-1, 2], steer in [-1, 1]."""
    r = watched.result
    mi = np.nan_to_num(np.asarray(r.mutual_information, float), nan=0.0)
    return [
        (np.asarray(r.eta2, float), 0.0, 1.0),
        (mi, 0.0, max(float(mi.max()) if len(mi) else 0.0, 1e-6)),
        (np.asarray(r.warning, float), -1.0, 2.0),
        (watched.steer, -1.0, 1.0),
    ]


def _top_down_transform(x: np.ndarray, y: np.ndarray, placer: FailurePlacer):
    """World metres → pixels of the top-down panel, fitting the route and the path, north up."""
    all_x = np.concatenate([np.asarray(x, float), placer.route[:, 0]])
    all_y = np.concatenate([np.asarray(y, float), placer.route[:, 1]])
    left, top, w, h = TOP_DOWN
    span = max(float(np.ptp(all_x)), float(np.ptp(all_y)) * w / h, 1e-6) * 1.1
    scale = w / span
    cx, cy = float(all_x.min() + all_x.max()) / 2, float(all_y.min() + all_y.max()) / 2

    def to_pixel(px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return left + w / 2 + (px - cx) * scale, top + h / 2 - (py - cy) * scale

    return to_pixel


def _background(title: str, series, placer: FailurePlacer, to_pixel) -> np.ndarray:
    """What every picture shares: title, panels' frames, the route and safe set, each strip's whole series in grey."""
    picture = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    cv2.putText(picture, title[:58], (8, 19), FONT, SMALL, INK, 1, cv2.LINE_AA)
    x, y, w, h = TOP_DOWN
    cv2.rectangle(picture, (x, y), (x + w - 1, y + h - 1), GREY, 1)
    cv2.putText(picture, "top-down view", (x + 4, y + 16), FONT, SMALL, INK, 1, cv2.LINE_AA)
    if len(placer.route):
        line = np.stack(to_pixel(placer.route[:, 0], placer.route[:, 1]), axis=1).astype(np.int32)
        cv2.polylines(picture, [line], False, GREY, 1, cv2.LINE_AA)
    for edge in placer.edges:
        cv2.polylines(picture, [np.stack(to_pixel(edge[:, 0], edge[:, 1]), axis=1).astype(np.int32)], False, INK, 1)
    _legend(picture)  # over the route and edges where they pass under it
    for i, (values, low, high) in enumerate(series):
        top = TITLE_H + VIEW_H + 8 + i * STRIP_H
        cv2.putText(picture, STRIP_LABELS[i], (8, top + 16), FONT, SMALL, INK, 1, cv2.LINE_AA)
        cv2.rectangle(picture, (120, top), (WIDTH - 8, top + STRIP_H - 6), GREY, 1)
        _trace(picture, values, low, high, top, len(values), GREY, len(values))
        if not np.isfinite(np.asarray(values, float)).any():
            why = EMPTY_STRIP.get(STRIP_LABELS[i], "none recorded")
            cv2.putText(picture, why, (130, top + 24), FONT, SMALL, GREY, 1, cv2.LINE_AA)
    return picture


def _legend(picture: np.ndarray) -> None:
    """What each colour of the top-down view is, along its bottom edge."""
    x, y, w, h = TOP_DOWN
    cv2.rectangle(picture, (x + 2, y + h - 46), (x + w - 3, y + h - 3), (255, 255, 255), -1)
    for i, (label, colour) in enumerate(LEGEND):
        row, col = divmod(i, 2)
        left, base = x + 8 + col * 150, y + h - 30 + row * 18
        cv2.line(picture, (left, base - 4), (left + 16, base - 4), colour, 3)
        cv2.putText(picture, label, (left + 22, base), FONT, 0.5 if len(label) < 16 else 0.45, INK, 1, cv2.LINE_AA)


def _trace(picture, values, low, high, top, count, colour, steps) -> None:
    """The first ``count`` of a strip's ``values`` as a line (NaN: a gap)."""
    left, right, h = 121, WIDTH - 9, STRIP_H - 8
    if steps < 1 or count < 1:
        return
    xs = left + (right - left) * np.arange(count) / max(steps - 1, 1)
    scaled = (np.clip(np.asarray(values[:count], float), low, high) - low) / (high - low)
    ys = top + 1 + h * (1 - scaled)
    finite = ~np.isnan(ys)
    if finite.sum() >= 1:
        line = np.stack([xs[finite], ys[finite]], axis=1).astype(np.int32)
        cv2.polylines(picture, [line], False, colour, 1, cv2.LINE_AA)


def _strips(picture, series, k: int, steps: int) -> None:
    """The strips up to step ``k`` in colour, a cursor at ``k`` and the value there."""
    for i, (values, low, high) in enumerate(series):
        top = TITLE_H + VIEW_H + 8 + i * STRIP_H
        _trace(picture, values, low, high, top, k + 1, PATH, steps)
        cursor = 121 + (WIDTH - 130) * k // max(steps - 1, 1)
        cv2.line(picture, (cursor, top), (cursor, top + STRIP_H - 6), BAD, 1)
        value = float(values[k]) if k < len(values) else math.nan
        text = _strip_text(STRIP_LABELS[i], value)
        cv2.putText(picture, text, (8, top + 34), FONT, SMALL, INK, 1, cv2.LINE_AA)


def _strip_text(label: str, value: float) -> str:
    """A strip's value at the cursor: a warning tier by name (-1: none raised), every other value to two places."""
    if math.isnan(value):
        return "-"
    if label == "warning tier":
        return "none" if value < 0 else f"warning {int(value)}"
    return f"{value:.2f}"


def _camera(picture: np.ndarray, frame: np.ndarray | None) -> None:
    """The network's grey frame, 4x, nearest neighbour (its pixels as the network has them)."""
    x, y, w, h = CAMERA
    cv2.putText(picture, "network input", (x, y - 6), FONT, SMALL, INK, 1, cv2.LINE_AA)
    if frame is None:
        cv2.rectangle(picture, (x, y), (x + w - 1, y + h - 1), GREY, 1)
        return
    big = cv2.resize(frame, (w, h), interpolation=cv2.INTER_NEAREST)
    picture[y : y + h, x : x + w] = cv2.cvtColor(big, cv2.COLOR_GRAY2BGR)
