"""Rerun bridge: camera frusta, subsampled images and silhouettes, the 3-D skeleton, per-frame metrics.

Entity layout (world = the tracker's frame, metres, Z up)::

    world/cameras/<cam>            Transform3D (cam2world) + Pinhole (K, resolution, RDF)  [static]
    world/cameras/<cam>/image      camera frame (JPEG/PNG passed through undecoded; raw as Image)
    world/cameras/<cam>/silhouette SegmentationImage from the chamfer images (1 = person)
    world/skeleton                 Points3D with keypoint ids (AnnotationContext: names + bones [static])
    metrics/{rms_px,latency_ms,cameras,ok}   Scalars

Timelines: ``frame`` (frame id) and ``capture_time`` (timestamp_ns).  The bridge is a separate zenoh
subscriber with newest-wins queues, so neither the tracker nor the cameras ever wait for the viewer.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import rerun as rr

from service.wire.messages import ChamferMessage, FrameMessage, MessageError
from service.wire.records import PoseRecord

#: bones between DESIGN.md joint names (a joint missing from a record is simply not drawn)
BONES = (("pelvis", "spine"), ("spine", "neck"), ("neck", "head"),
         ("neck", "left_shoulder"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
         ("neck", "right_shoulder"), ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
         ("pelvis", "left_hip"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
         ("pelvis", "right_hip"), ("right_hip", "right_knee"), ("right_knee", "right_ankle"))
DEFAULT_JOINTS = ("pelvis", "spine", "neck", "head", "left_shoulder", "left_elbow", "left_wrist",
                  "right_shoulder", "right_elbow", "right_wrist", "left_hip", "left_knee", "left_ankle",
                  "right_hip", "right_knee", "right_ankle")


class RerunBridge:
    """Log studio data to a rerun ``RecordingStream`` (see module docstring).

    ``image_every``: log one image/silhouette per camera every that many frames.
    """

    def __init__(self, recording: rr.RecordingStream, *, cameras: Sequence = (), image_every: int = 5,
                 joint_names: Sequence[str] = DEFAULT_JOINTS) -> None:
        self.rec, self.image_every = recording, max(1, int(image_every))
        self.joint_names = list(joint_names)
        self.logged = {"poses": 0, "images": 0, "silhouettes": 0}
        self._log_static(cameras)

    def _log_static(self, cameras: Sequence) -> None:
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for cam in cameras:
            w, h = cam.size
            rec.log(f"world/cameras/{cam.name}",
                    rr.Transform3D(translation=cam.center, mat3x3=np.asarray(cam.rotation).T), static=True)
            rec.log(f"world/cameras/{cam.name}",
                    rr.Pinhole(image_from_camera=np.asarray(cam.matrix), resolution=[w, h],
                               camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3), static=True)
        self._log_skeleton_static()
        rec.log("world/cameras", rr.AnnotationContext([rr.ClassDescription(
            info=rr.AnnotationInfo(id=1, label="person", color=(255, 64, 64, 128)))]), static=True)

    def _log_skeleton_static(self) -> None:
        ids = {n: i for i, n in enumerate(self.joint_names)}
        self.rec.log("world/skeleton", rr.AnnotationContext([rr.ClassDescription(
            info=rr.AnnotationInfo(id=0, label="person"),
            keypoint_annotations=[rr.AnnotationInfo(id=i, label=n) for n, i in ids.items()],
            keypoint_connections=[(ids[a], ids[b]) for a, b in BONES if a in ids and b in ids])]), static=True)

    def _time(self, frame_id: int, timestamp_ns: int) -> None:
        self.rec.set_time("frame", sequence=int(frame_id))
        self.rec.set_time("capture_time", duration=int(timestamp_ns) * 1e-9)

    def on_pose(self, pose: PoseRecord) -> None:
        """Skeleton (if the record has joints) and metrics of one frame."""
        rec = self.rec
        self._time(pose.frame, pose.timestamp_ns)
        joints = pose.get("joints") or {}
        new = [n for n in joints if n not in self.joint_names]
        if new:  # a model with more joints than the default list: extend the static description once
            self.joint_names += new
            self._log_skeleton_static()
        names = [n for n in self.joint_names if n in joints]
        if names:
            rec.log("world/skeleton", rr.Points3D(np.array([joints[n] for n in names]), class_ids=0,
                                                  keypoint_ids=[self.joint_names.index(n) for n in names],
                                                  radii=0.02))
        for key in ("rms_px", "latency_ms", "cameras"):
            if pose.get(key) is not None:
                rec.log(f"metrics/{key}", rr.Scalars(float(pose.get(key))))
        rec.log("metrics/ok", rr.Scalars(1.0 if pose.ok else 0.0))
        self.logged["poses"] += 1

    def wants(self, frame_id: int) -> bool:
        """Whether frame ``frame_id``'s images are logged (every ``image_every``-th)."""
        return frame_id % self.image_every == 0

    def on_frame(self, frame: FrameMessage) -> None:
        """One camera image (only frames with ``wants(frame_id)``); JPEG/PNG are not decoded here."""
        if not self.wants(frame.frame_id):
            return
        self._time(frame.frame_id, frame.timestamp_ns)
        path = f"world/cameras/{frame.camera}/image"
        if frame.encoding == "raw":
            img = frame.image()
            self.rec.log(path, rr.Image(img, color_model="BGR" if img.ndim == 3 else "L"))
        else:
            self.rec.log(path, rr.EncodedImage(contents=frame.data, media_type=f"image/{frame.encoding}"))
        self.logged["images"] += 1

    def on_chamfer(self, msg: ChamferMessage) -> None:
        """The silhouette (distance 0 = inside) of segmentation chamfer images, as a segmentation image."""
        if not self.wants(msg.frame_id):
            return
        try:
            sil = msg.array("silhouette")
        except KeyError:
            return
        w, h = msg.image_size
        mask = np.zeros((h, w), np.uint8)
        x0, y0 = msg.roi_xy
        mask[y0:y0 + sil.shape[0], x0:x0 + sil.shape[1]] = sil == 0
        self._time(msg.frame_id, msg.timestamp_ns)
        self.rec.log(f"world/cameras/{msg.camera}/silhouette", rr.SegmentationImage(mask))
        self.logged["silhouettes"] += 1


def cameras_for_view(calibration_path) -> list:
    """Cameras of a calibration TOML for the frusta (MessageError naming the file if unreadable)."""
    from capture.calibration import CalibrationError, load_calibration

    try:
        return load_calibration(calibration_path)
    except (CalibrationError, OSError) as exc:
        raise MessageError(f"{calibration_path}: {exc}") from None
