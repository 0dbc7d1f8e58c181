"""`contourcap export --bvh` imported by Blender with its default settings (Debian's `blender`, headless
`import_anim.bvh`): the skeleton stands upright (head above pelvis on Blender's Z), its joints are within
25 mm of the records, and the take keeps its length (one Blender frame per frame id, Frame Time 1/fps).
Skipped where `blender` is not installed."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

pytest.importorskip("tracker.synthetic.retarget")

from tests.support.outputs import FIRST_ID, FPS, make_take  # noqa: E402
from service.cli import main  # noqa: E402
from service.export import write_pose_records  # noqa: E402

BLENDER = shutil.which("blender")
SCRIPT = r"""
import builtins, json, sys
import bpy
# Debian's Blender 3.4 runs on Python 3.11, where its BVH importer's open(path, 'rU') fails: drop the 'U'
_open = builtins.open
builtins.open = lambda file, mode="r", *a, **k: _open(file, mode.replace("U", ""), *a, **k)
bvh, out = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.import_anim.bvh(filepath=bvh)  # the importer's defaults: what a user clicks
obj = bpy.context.selected_objects[0]
action = obj.animation_data.action
first, last = (int(round(v)) for v in action.frame_range)
frames = []
for f in range(first, last + 1):
    bpy.context.scene.frame_set(f)
    frames.append({b.name: [list(obj.matrix_world @ b.head), list(obj.matrix_world @ b.tail)] for b in obj.pose.bones})
json.dump({"frame_range": [first, last], "frames": frames}, open(out, "w"))
"""
PART_JOINT = {"pelvis": "pelvis", "torso": "spine", "left_upper_arm": "left_shoulder", "left_forearm": "left_elbow",
              "left_hand": "left_wrist", "right_upper_arm": "right_shoulder", "right_forearm": "right_elbow",
              "right_hand": "right_wrist", "left_shank": "left_knee", "right_shank": "right_knee"}
# (the thigh bones start at the thighs' origins, the model's pivots; the reported hip joint centres
# are points of the pelvis inside them: tracker.body.model.PIVOT_PART)


@pytest.mark.skipif(BLENDER is None, reason="blender not installed (Debian: apt-get install blender)")
def test_bvh_imported_by_blender_defaults_stands_upright(tmp_path):
    records, truth = make_take()
    poses = tmp_path / "poses.jsonl"
    write_pose_records(poses, records)
    bvh = tmp_path / "take.bvh"
    assert main(["export", str(poses), "--bvh", str(bvh), "--height-m", repr(truth["model"].height_m)]) == 0
    frame_time = float(next(line for line in bvh.read_text().splitlines() if line.startswith("Frame Time:")).split()[2])
    assert frame_time == pytest.approx(1 / FPS, rel=1e-6)
    script = tmp_path / "read.py"
    script.write_text(SCRIPT)
    out = tmp_path / "blender.json"
    proc = subprocess.run([BLENDER, "-b", "--factory-startup", "-noaudio", "--python", str(script), "--",
                           str(bvh), str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and out.exists(), proc.stdout[-2000:] + proc.stderr[-2000:]
    got = json.loads(out.read_text())
    n = truth["frames"].size  # frame ids 13..102 with gaps: 90 Blender frames = 3.0 s at 30 fps
    assert got["frame_range"][1] - got["frame_range"][0] + 1 == n
    held = None
    worst = 0.0
    for k, fid in enumerate(truth["frames"]):
        rec = next((r for r in records if r.frame == fid and r.ok), None)
        held = rec or held  # a frame without an ok pose holds the previous one
        bones = got["frames"][k]
        head_top, pelvis = bones["head"][1], bones["pelvis"][0]
        assert head_top[2] - pelvis[2] > 0.3  # upright on Blender's Z
        for part, joint in PART_JOINT.items():
            worst = max(worst, float(np.linalg.norm(np.subtract(bones[part][0], held.get("joints")[joint]))))
    assert worst < 0.025
    assert FIRST_ID == truth["frames"][0]
