"""`contourcap export` to TRC, C3D and CSV: each file read back by a reader other than its writer and
compared with the pose records (every joint of every ok frame within 0.01 mm after units and axes;
gaps where a frame is not ok or was never delivered; frame rate and frame ids kept)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("tracker.synthetic.retarget")

from tests.support.outputs import FIRST_ID, FPS, MISSING, NOT_OK, make_take  # noqa: E402
from service.cli import main  # noqa: E402
from service.export import write_pose_records  # noqa: E402

Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # (x, y, z) -> (x, z, -y), as the help says


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    records, truth = make_take()
    path = tmp_path_factory.mktemp("take") / "poses.jsonl"
    write_pose_records(path, records)
    return path, records, truth


def _expected(records, truth, axes, scale):
    """(n_rows, n_joints, 3) on the frame grid, NaN where there is no ok record."""
    frames = truth["frames"]
    X = np.full((frames.size, len(truth["names"]), 3), np.nan)
    for r in records:
        if r.ok:
            X[r.frame - frames[0]] = [r.get("joints")[n] for n in truth["names"]]
    return X @ axes.T * scale


def _tokenize(line: str) -> list[str]:
    """OpenSim's FileAdapter::tokenize with delimiters "\\t\\r": empty cells kept, a trailing one dropped."""
    tokens, start = [], 0
    while True:
        i = min((j for j in (line.find("\t", start), line.find("\r", start)) if j >= 0), default=-1)
        if i < 0:
            break
        tokens.append(line[start:i].strip())
        start = i + 1
    if len(line) > start:
        tokens.append(line[start:].strip())
    return tokens


def read_trc_like_opensim(path):
    """The checks and parse of OpenSim's TRCFileAdapter::extendRead, in Python (no library reads TRC here)."""
    lines = path.read_text().split("\n")
    assert lines[0].split()[0] == "PathFileType"
    keys = [k for k in _tokenize(lines[1]) if k]
    assert keys == ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                    "OrigDataStartFrame", "OrigNumFrames"]
    values = [v for v in _tokenize(lines[2]) if v]
    assert len(values) == len(keys)
    meta = dict(zip(keys, values))
    n_markers = int(meta["NumMarkers"])
    labels = [c for c in _tokenize(lines[3]) if c]
    assert len(labels) == n_markers + 2 and labels[:2] == ["Frame#", "Time"]
    xyz = [c for c in _tokenize(lines[4]) if c]
    assert xyz == [f"{a}{i}" for i in range(1, n_markers + 1) for a in "XYZ"]
    i = 5
    while not _tokenize(lines[i]) or not _tokenize(lines[i])[0]:  # blank lines between header and data
        i += 1
    frames, times, data = [], [], []
    while i < len(lines) and _tokenize(lines[i]):  # an empty line ends the data
        row = _tokenize(lines[i])
        assert len(row) == n_markers * 3 + 2, f"line {i + 1}: {len(row)} cells"
        frames.append(int(row[0]))
        times.append(float(row[1]))
        data.append([[float(row[c + k]) if all(row[c:c + 3]) else np.nan for k in range(3)]
                     for c in range(2, n_markers * 3 + 2, 3)])
        i += 1
    assert all(not line.strip() for line in lines[i:])
    return meta, labels[2:], np.array(frames), np.array(times), np.array(data)


@pytest.mark.parametrize("units,up", [("mm", None), ("m", "z")])
def test_trc_reads_back_as_opensim_reads_it(take, tmp_path, units, up, capsys):
    path, records, truth = take
    out = tmp_path / "take.trc"
    argv = ["export", str(path), "--trc", str(out), "--units", units] + (["--up", up] if up else [])
    assert main(argv) == 0
    assert "16 markers, 90 frames (ids 13..102) at 30.00 fps, 8 gaps" in capsys.readouterr().out
    meta, names, frames, times, X = read_trc_like_opensim(out)
    assert names == truth["names"]
    assert float(meta["DataRate"]) == pytest.approx(FPS) and float(meta["CameraRate"]) == pytest.approx(FPS)
    assert (meta["Units"], int(meta["NumFrames"]), int(meta["OrigDataStartFrame"])) == (units, 90, FIRST_ID)
    np.testing.assert_array_equal(frames, truth["frames"])
    np.testing.assert_allclose(times, (frames - FIRST_ID) / FPS, atol=1e-6)
    scale = 1000.0 if units == "mm" else 1.0
    want = _expected(records, truth, np.eye(3) if up == "z" else Y_UP, scale)  # TRC default: Y up
    gap = np.isnan(want[:, :, 0])
    np.testing.assert_array_equal(np.isnan(X[:, :, 0]), gap)
    assert set(truth["frames"][gap.all(axis=1)]) == set(NOT_OK) | set(MISSING)
    assert np.nanmax(np.abs(X - want)) / scale * 1000 < 0.01  # mm


def _read_c3d(path):
    """Points (n_frames, n_markers, 3) with NaN where invalid, labels, rate, first frame id, units, y-screen."""
    try:
        import ezc3d  # the other C3D implementation (C++), not the writer's
    except ImportError:
        ezc3d = None
    if ezc3d is not None:
        c = ezc3d.c3d(str(path))
        P = c["data"]["points"][:3].transpose(2, 1, 0)
        res = c["data"]["meta_points"]["residuals"][0].T
        P = np.where(res[..., None] < 0, np.nan, P)
        par = c["parameters"]["POINT"]
        return (P, list(par["LABELS"]["value"]), float(par["RATE"]["value"][0]),
                int(c["header"]["points"]["first_frame"]), par["UNITS"]["value"][0].strip(),
                par["Y_SCREEN"]["value"][0].strip())
    import c3d  # fallback: the writer's own library reads it back

    with open(path, "rb") as f:
        r = c3d.Reader(f)
        pts = np.array([p for _, p, _ in r.read_frames()])
        P = np.where(pts[..., 3:4] < 0, np.nan, pts[..., :3])
        return (P, [s.strip() for s in r.point_labels], float(r.point_rate), int(r.first_frame) - 1,
                r.get("POINT:UNITS").string_value.strip(), r.get("POINT:Y_SCREEN").string_value.strip())


@pytest.mark.parametrize("units,up", [("mm", None), ("m", "y")])
def test_c3d_reads_back_with_the_other_library(take, tmp_path, units, up):
    path, records, truth = take
    out = tmp_path / "take.c3d"
    argv = ["export", str(path), "--c3d", str(out), "--units", units] + (["--up", up] if up else [])
    assert main(argv) == 0
    P, labels, rate, first, file_units, y_screen = _read_c3d(out)
    assert labels == truth["names"] and rate == pytest.approx(FPS) and file_units == units
    assert first == FIRST_ID  # ezc3d counts from 0: C3D frame 14 (1-based) is pose frame 13
    assert y_screen == ("+Y" if up == "y" else "+Z")  # C3D default: Z up
    scale = 1000.0 if units == "mm" else 1.0
    want = _expected(records, truth, Y_UP if up == "y" else np.eye(3), scale)
    assert P.shape == want.shape
    np.testing.assert_array_equal(np.isnan(P[:, :, 0]), np.isnan(want[:, :, 0]))
    assert np.nanmax(np.abs(P - want)) / scale * 1000 < 0.01  # mm (float32 storage)


def test_csv_one_row_per_record(take, tmp_path):
    path, records, truth = take
    out = tmp_path / "take.csv"
    assert main(["export", str(path), "--csv", str(out)]) == 0
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["frame"]) for r in rows] == [r.frame for r in records]
    for row, rec in zip(rows, records):
        assert float(row["time_s"]) == pytest.approx((rec.frame - FIRST_ID) / FPS, abs=1e-6)
        assert row["ok"] == str(int(rec.ok))
        for name in truth["names"]:
            cells = [row[f"{name}_{a}"] for a in "xyz"]
            if rec.ok:
                np.testing.assert_allclose([float(c) for c in cells], np.array(rec.get("joints")[name]) * 1000,
                                           atol=1e-5)
            else:
                assert cells == ["", "", ""]


def test_export_errors_are_one_line(take, tmp_path, capsys):
    path, _, _ = take
    assert main(["export", str(path)]) == 2
    assert "at least one of" in capsys.readouterr().err
    assert main(["export", str(path), "--trc", str(tmp_path / "x.trc"), "--smooth", "gauss"]) == 2
    assert "--smooth" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "none.jsonl"), "--trc", str(tmp_path / "x.trc")]) == 2
    assert "cannot read" in capsys.readouterr().err
