"""Review a take: the fitted model drawn over every camera's images (``contourcap review``).

For each frame of a session that has a pose record: the model named in the record (sized by the
session's ``[subject]``, as the tracker sizes it) is posed with the record's ``params`` and its
extremal contours are drawn per camera, coloured by side (``tracker.imaging.overlay``); the record's joints
as a skeleton (names on demand); the frame's status (ok, or the reason it is not; rms; IoU when the
record has one).  Cameras are tiled into one image per frame, written as a video;
a contact sheet shows a few evenly spaced frames, each camera cropped to the person.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from capture.atomic import atomic_path
from capture.replay import iter_frame_sets
from capture.session import Session
from service.errors import ServiceError
from service.offline import session_model
from tracker.body.kinematics import forward
from tracker.body.model import BodyModel, available_models
from tracker.imaging.contours import extremal_contours
from tracker.imaging.overlay import draw_contours, draw_skeleton, draw_text, resize_to_width, side_colours, tile_images

__all__ = ["ReviewError", "load_records", "status_lines", "FrameOverlay", "ReviewSummary", "write_review"]


class ReviewError(ServiceError, ValueError):
    """A pose file or record that cannot be reviewed (the message names the file and line)."""


def load_records(path: Path) -> list[dict]:
    """Pose records of a JSONL file, each checked to be an object with an integer ``frame``.

    ``params`` (when present) must be a list of numbers and ``joints`` an object; the model is
    checked later against the record's ``params`` (``FrameOverlay.check``).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ReviewError(f"{path}: cannot read pose records ({exc})") from None
    records = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        where = f"{path}:{lineno}"
        try:
            rec = json.loads(line)
        except ValueError as exc:
            raise ReviewError(f"{where}: not a JSON pose record ({exc})") from None
        if not isinstance(rec, dict) or not isinstance(rec.get("frame"), int) or rec["frame"] < 0:
            raise ReviewError(f"{where}: a pose record is a JSON object with a non-negative integer 'frame'")
        params = rec.get("params")
        if params is not None and (not isinstance(params, list)
                                   or not all(isinstance(v, (int, float)) for v in params)):
            raise ReviewError(f"{where}: 'params' must be a list of numbers")
        if rec.get("joints") is not None and not isinstance(rec["joints"], dict):
            raise ReviewError(f"{where}: 'joints' must be an object of name: [x, y, z]")
        rec["_line"] = lineno
        records.append(rec)
    if not records:
        raise ReviewError(f"{path}: no pose record")
    return records




def status_lines(record: dict | None, frame_id: int) -> list[str]:
    """The text shown for a frame: status (ok / the reason it is not), rms, IoU, iterations."""
    if record is None:
        return [f"frame {frame_id}: no pose record"]
    head = f"frame {frame_id}: " + ("ok" if record.get("ok") else f"NOT OK: {record.get('reason') or 'no reason given'}")
    figures = []
    if isinstance(record.get("rms_px"), (int, float)):
        figures.append(f"rms {record['rms_px']:.2f} px")
    iou = record.get("iou")
    if isinstance(iou, (int, float)) and not isinstance(iou, bool):
        figures.append(f"IoU {iou:.2f}")
    if isinstance(record.get("iterations"), int):
        figures.append(f"{record['iterations']} it")
    return [head] + (["  ".join(figures)] if figures else [])


class FrameOverlay:
    """Draws pose records over one session's camera images.

    Parameters
    ----------
    session : Session
    names : bool
        Write joint names beside the joints.
    n_samples : int
        Contour points per ruling.
    """

    def __init__(self, session: Session, *, names: bool = False, n_samples: int = 12):
        self.session = session
        self.names = names
        self.n_samples = n_samples
        self.camera_names = list(session.camera_names)
        self.cameras = {n: session.camera_model(n) for n in self.camera_names}
        self._models: dict[str, BodyModel] = {}

    def model(self, name: str) -> BodyModel:
        """The body model ``name`` sized by the session's subject (cached)."""
        if name not in self._models:
            if name not in available_models():
                raise ReviewError(f"unknown model {name!r} (have {available_models()})")
            self._models[name] = session_model(self.session, name)
        return self._models[name]

    def check(self, record: dict, where: str) -> None:
        """ReviewError unless the record's ``params`` fit its model (records without params pass)."""
        if record.get("params") is None:
            return
        name = record.get("model", "knossow40")
        try:
            model = self.model(name)
        except ReviewError as exc:
            raise ReviewError(f"{where}: {exc}") from None
        p = np.asarray(record["params"], float)
        if p.shape != (model.n_params,) or not np.all(np.isfinite(p)):
            raise ReviewError(f"{where}: 'params' has {p.size} values (finite: {bool(np.all(np.isfinite(p)))}), "
                              f"model {name!r} needs {model.n_params} finite values")

    def draw(self, images: dict[str, np.ndarray], record: dict | None) -> tuple[dict[str, np.ndarray], dict]:
        """Overlay ``record`` on copies of ``images`` (camera -> (h, w, 3) BGR).

        Returns the drawn images and, per camera, the pixel box ``(x0, y0, x1, y1)`` of what was drawn
        (absent when nothing of the body projects into that camera).
        """
        names = [n for n in self.camera_names if n in images]
        out = {n: np.ascontiguousarray(images[n]).copy() for n in names}
        boxes: dict[str, list] = {n: [] for n in names}
        if record is not None and record.get("params") is not None and names:
            model = self.model(record.get("model", "knossow40"))
            pose = forward(model, np.asarray(record["params"], float))
            cams = [self.cameras[n] for n in names]
            con = extremal_contours(model, pose, cams, n_samples=self.n_samples, visibility=True)
            uv = con.shaped(con.uv)            # (c, p, 2, s, 2)
            vis = con.shaped(con.visible)      # (c, p, 2, s)
            colours = np.repeat(side_colours(model.part_names), 2, axis=0)  # (p * 2, 3): rows (part, side)
            for i, n in enumerate(names):
                u = uv[i].reshape(-1, self.n_samples, 2)
                v = vis[i].reshape(-1, self.n_samples)
                draw_contours(out[n], u, v, colours)
                if v.any():
                    boxes[n].append(u[v])
        joints = (record or {}).get("joints") or {}
        for n in names:
            cam = self.cameras[n]
            pts = {}
            for j, X in joints.items():
                X = np.asarray(X, float)
                if X.shape == (3,) and np.all(np.isfinite(X)) and cam.depth(X) > 1e-3:
                    pts[j] = cam.project(X)
            draw_skeleton(out[n], pts, names=self.names)
            if pts:
                boxes[n].append(np.array(list(pts.values())))
        box = {}
        for n, pts in boxes.items():
            if pts:
                p = np.concatenate(pts)
                h, w = out[n].shape[:2]
                p = p[(p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)]
                if len(p):
                    box[n] = (*p.min(axis=0), *p.max(axis=0))
        return out, box


@dataclass(frozen=True)
class ReviewSummary:
    """frames: frames written; with_record / ok: how many had a record / were ok; video, sheet: paths
    (None when not written); size: video frame (width, height)."""

    frames: int
    with_record: int
    ok: int
    video: str | None
    sheet: str | None
    size: tuple[int, int] | None


def _label(image: np.ndarray, cam: str) -> np.ndarray:
    return draw_text(image, [cam], colour=(255, 255, 255))


def _header(width: int, lines: list[str], record: dict | None, scale: float = 0.55, n_lines: int = 2) -> np.ndarray:
    """A black band ``width`` pixels wide with the frame's status lines (green ok, red otherwise), at
    least ``n_lines`` lines high (so every frame of a video has the same size)."""
    lines = list(lines) + [""] * (n_lines - len(lines))
    colour = (80, 255, 80) if record is not None and record.get("ok") else (90, 90, 255)
    (_, h), base = cv2.getTextSize("Mg", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    step = h + base + 4
    band = np.zeros((step * len(lines) + 6, width, 3), np.uint8)
    for i, t in enumerate(lines):
        cv2.putText(band, t, (6, (i + 1) * step - base + 2), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1,
                    cv2.LINE_AA)
    return band


def _pad_to(image: np.ndarray, h: int, w: int) -> np.ndarray:
    if image.shape[:2] == (h, w):
        return image
    out = np.zeros((h, w, 3), np.uint8)
    out[: image.shape[0], : image.shape[1]] = image[:h, :w]
    return out


def _crop(image: np.ndarray, box, pad: float = 0.35) -> np.ndarray:
    h, w = image.shape[:2]
    if box is None:
        return image
    x0, y0, x1, y1 = box
    m = pad * max(x1 - x0, y1 - y0) + 16
    x0, y0 = int(max(0, x0 - m)), int(max(0, y0 - m))
    x1, y1 = int(min(w, x1 + m)), int(min(h, y1 + m))
    return image if x1 - x0 < 8 or y1 - y0 < 8 else image[y0:y1, x0:x1]


def write_review(session: Session, records: Sequence[dict], *, video: Path | None = None,
                 sheet: Path | None = None, frames: range | None = None, names: bool = False,
                 sheet_frames: int = 6, video_width: int = 1920, sheet_width: int = 1600,
                 progress: Callable[[int, int, str], None] | None = None,
                 source: str = "poses") -> ReviewSummary:
    """Write the review video and/or the contact sheet.

    Parameters
    ----------
    session : Session
    records : sequence of dict
        Pose records (``load_records``), any order; a later record of the same frame wins.
    video, sheet : Path, optional
        Output video (mp4v in .mp4, MJPG in .avi) and PNG contact sheet; at least one.
    frames : range, optional
        Frame ids to review (default: from the first to the last record's frame).
    sheet_frames : int
        Frames on the contact sheet, evenly spaced over the reviewed frames that have a record.
    video_width, sheet_width : int
        Largest width in pixels of a video frame / of the sheet.
    progress : callable, optional
        ``progress(done, total, label)`` after each frame.
    source : str
        Name of the records' file in error messages.
    """
    if video is None and sheet is None:
        raise ReviewError("nothing to write: give a video (--out) and/or a sheet (--sheet)")
    overlay = FrameOverlay(session, names=names)
    by_frame = {}
    for r in records:
        overlay.check(r, f"{source}:{r.get('_line', '?')} (frame {r['frame']})")
        by_frame[r["frame"]] = r
    lo, hi = min(by_frame), max(by_frame) + 1
    if frames is not None:
        lo, hi = max(lo, frames.start), min(hi, frames.stop)
    if hi <= lo:
        raise ReviewError(f"{source}: no pose record in frames {frames.start}:{frames.stop}")
    picks = sorted(f for f in by_frame if lo <= f < hi)
    picks = [picks[i] for i in np.unique(np.linspace(0, len(picks) - 1, max(1, sheet_frames)).round().astype(int))]
    cams = overlay.camera_names
    th = max(overlay.cameras[n].height for n in cams)
    tw = max(overlay.cameras[n].width for n in cams)
    kept: dict[int, tuple[dict, dict]] = {}
    total = hi - lo
    outputs = contextlib.ExitStack()  # the video is written to a temporary file, renamed when complete
    if video is not None:
        video.parent.mkdir(parents=True, exist_ok=True)
        tmp_video = outputs.enter_context(atomic_path(video))
    with outputs:
        n_frames, n_rec, n_ok, size = _render(session, overlay, by_frame, picks, lo, hi, video,
                                              tmp_video if video is not None else None, sheet, kept, th, tw,
                                              video_width, progress, total)
    if sheet is not None:
        _write_sheet(sheet, overlay, kept, by_frame, sheet_width)
    return ReviewSummary(n_frames if video is not None else len(kept), n_rec, n_ok,
                         None if video is None else str(video), None if sheet is None else str(sheet), size)


def _render(session, overlay, by_frame, picks, lo, hi, video, tmp_video, sheet, kept, th, tw, video_width, progress,
            total):
    """Draw every reviewed frame into ``tmp_video`` (and keep the sheet's picks in ``kept``);
    returns ``(frames, records, ok records, video size)``."""
    cams = overlay.camera_names
    writer, size, n_frames, n_rec, n_ok = None, None, 0, 0, 0
    try:
        for fid, group in iter_frame_sets(session, frames=range(lo, hi)):
            rec = by_frame.get(fid)
            n_rec += rec is not None
            n_ok += bool(rec is not None and rec.get("ok"))
            if video is None and fid not in picks:
                continue
            drawn, box = overlay.draw({n: f.image for n, f in group.items()}, rec)
            if fid in picks and sheet is not None:
                kept[fid] = (drawn, box)
            if video is not None:
                tiles = [_label(_pad_to(drawn[n], th, tw), n) if n in drawn
                         else _label(np.zeros((th, tw, 3), np.uint8), f"{n}: no image") for n in cams]
                grid = tile_images(tiles)
                scale = float(np.clip(grid.shape[1] / 1600, 0.45, 0.8))
                img = np.concatenate([_header(grid.shape[1], status_lines(rec, fid), rec, scale=scale), grid])
                img = resize_to_width(img, video_width, even=True)
                if size is not None and (img.shape[1], img.shape[0]) != size:  # a video has one frame size
                    img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
                if writer is None:
                    size = (img.shape[1], img.shape[0])
                    fourcc = "MJPG" if video.suffix.lower() == ".avi" else "mp4v"
                    writer = cv2.VideoWriter(str(tmp_video), cv2.VideoWriter_fourcc(*fourcc), float(session.fps),
                                             size)
                    if not writer.isOpened():
                        raise ReviewError(f"{video}: cannot write a {fourcc} video here")
                writer.write(img)
            n_frames += 1
            if progress is not None:
                progress(fid - lo + 1, total, f"frame {fid}")
    finally:
        if writer is not None:
            writer.release()
    return n_frames, n_rec, n_ok, size


def _write_sheet(path: Path, overlay: FrameOverlay, kept: dict[int, tuple[dict, dict]], by_frame: dict,
                 width: int) -> None:
    """One cell per kept frame (a status band over its cameras side by side, each cropped to the union
    of that camera's drawn boxes over the kept frames); cells in two columns from 4 frames on."""
    if not kept:
        raise ReviewError("no frame for the sheet: the session holds none of the records' frames")
    cams = overlay.camera_names
    union = {}
    for _, box in kept.values():
        for n, b in box.items():
            u = union.get(n)
            union[n] = b if u is None else (min(u[0], b[0]), min(u[1], b[1]), max(u[2], b[2]), max(u[3], b[3]))
    n_cols = 2 if len(kept) >= 4 else 1
    crops = {fid: [_crop(kept[fid][0].get(n, np.zeros((overlay.cameras[n].height, overlay.cameras[n].width, 3),
                                                        np.uint8)), union.get(n)) for n in cams] for fid in kept}
    aspect = sum(c.shape[1] / c.shape[0] for c in next(iter(crops.values())))
    tallest = max(c.shape[0] for c in next(iter(crops.values())))
    tile_h = max(32, min(int((width / n_cols - 4) / aspect), 2 * tallest))  # never upscaled more than 2x
    cells = []
    for fid in sorted(kept):
        rec = by_frame.get(fid)
        row = [_label(cv2.resize(c, (max(1, round(c.shape[1] * tile_h / c.shape[0])), tile_h),
                                 interpolation=cv2.INTER_AREA if c.shape[0] > tile_h else cv2.INTER_LINEAR), n)
               for n, c in zip(cams, crops[fid])]
        row = np.concatenate(row, axis=1)
        cell = np.concatenate([_header(row.shape[1], status_lines(rec, fid), rec, scale=0.45), row])
        cells.append(np.pad(cell, ((0, 4), (0, 4), (0, 0))))
    ch, cw = max(c.shape[0] for c in cells), max(c.shape[1] for c in cells)
    cells = [_pad_to(c, ch, cw) for c in cells]
    sheet = tile_images(cells, cols=n_cols)
    sheet = resize_to_width(sheet, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), sheet, [cv2.IMWRITE_PNG_COMPRESSION, 6]):
            raise ReviewError(f"{path}: cannot write the sheet (a .png path is expected)")
