"""Articulated body models: truncated elliptical cones on zero-reference kinematic chains.

A model is a TOML file (``tracker/models/<name>.toml``) listing body parts in
topological order.  Each part has

- ``parent``: the name of an earlier part ("" or absent for the root, which is
  the only part with ``joint = "free"``: 3 translations + a rotation vector);
- ``offset``: the part origin (= its joint centre) in the parent frame at the
  reference pose, in fractions of body height;
- ``rotation``: the fixed part2parent rotation at the reference pose, degrees,
  applied as intrinsic X, then Y, then Z;
- ``dofs``: 0–3 rotational DOF, each ``{name, axis, limits}`` with ``axis`` one
  of ``x y z -x -y -z`` in the part frame and ``limits = [lo, hi]`` in degrees.
  A joint with several DOF rotates by ``Rot(axis1, λ1) Rot(axis2, λ2) ...``;
- ``cone``: the truncated elliptical cone of IJCV eq. 12 in the part frame,
  ``X(θ, z) = (a cos θ (1 + k z), b sin θ (1 + k z), z)`` for ``z in [z1, z2]``,
  with ``a, b, z1, z2`` in fractions of height and ``k`` in 1/height;
- ``segment`` (optional): a name a subject's explicit segment length may set
  (the part's cone and its children's offsets are stretched along its axis);
- ``width`` (optional): a name of a left-right width a subject may set (``hip_width``,
  ``shoulder_width``): the distance between the origins of the two parts carrying the name at
  the reference pose; a given width scales the lateral component (world y at the reference pose)
  of the part's ``offset`` so that its origin lies ± width / 2 from the midline;
- ``radius`` (optional): a name of a radius group a subject may scale (both cone axes), or
  ``radius_a`` / ``radius_b`` for one axis each (e.g. ``trunk_depth`` / ``trunk_width``).

``part2world = parent2world · Trans(offset) · Rot(rotation) · Rot(dofs)``, so
Φ = 0 is the reference pose (a T-pose facing +X, standing on z = 0 at the
origin): the zero-reference property of IJCV §3.2.

Sizing: lengths are multiplied by the subject's height.  The fractions follow
the segment-length table of D. A. Winter, *Biomechanics and Motor Control of
Human Movement*, 4th ed. (2009), Fig. 4.1 (after Drillis & Contini 1966):
hip 0.530 H, knee 0.285 H, ankle 0.039 H, shoulder 0.818 H, chin 0.870 H,
upper arm 0.186 H, forearm 0.146 H, hand 0.108 H, hip width 0.191 H,
shoulder width 0.259 H, foot length 0.152 H.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from capture.tomlio import load_file
from tracker.errors import TrackerError

__all__ = ["BodyModel", "ModelError", "load_model", "available_models", "JOINT_NAMES", "PIVOT_PART"]

MODELS_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_HEIGHT_M = 1.75

#: Joint-centre names every model provides (DESIGN.md pose record).
JOINT_NAMES = (
    "pelvis", "spine", "neck", "head",
    "left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist",
    "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle",
)  # fmt: skip

#: Joint -> the part whose origin the limb below turns about, where the reported joint centre
#: (``[joints]``) is not that origin: the hip joint centres are points of the pelvis inside the
#: thighs' origins.
PIVOT_PART = {"left_hip": "left_thigh", "right_hip": "right_thigh"}

_AXES = {
    "x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0),
    "-x": (-1.0, 0.0, 0.0), "-y": (0.0, -1.0, 0.0), "-z": (0.0, 0.0, -1.0),
}  # fmt: skip

# parameter kinds
ROOT_TRANSLATION, ROOT_ROTATION, JOINT_ROTATION = 0, 1, 2


class ModelError(TrackerError, ValueError):
    """A body-model file is invalid; the message names the file and the part."""


def euler_xyz_deg(angles) -> np.ndarray:
    """Intrinsic X-then-Y-then-Z rotation.

    Parameters
    ----------
    angles : (float, float, float)
        Degrees.

    Returns
    -------
    ndarray, shape (3, 3)
    """
    rx, ry, rz = np.radians(np.asarray(angles, dtype=float))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A sized body model.  All arrays are read-only.

    Attributes
    ----------
    name, height_m, part_names : str, float (metres), tuple of str (length n_parts)
    parent : ndarray of int, shape (n_parts,)
        Parent index, -1 for the root (index 0).
    offset : ndarray, shape (n_parts, 3)
        Part origin in the parent frame at the reference pose, metres.
    rest_rotation : ndarray, shape (n_parts, 3, 3)
        Fixed part2parent rotation at the reference pose.
    cones : ndarray, shape (n_parts, 5)
        ``(a, b, k, z1, z2)`` per part, metres (k in 1/m).
    param_names : tuple of str, length n_params
    param_kind : ndarray of int, shape (n_params,)
        ROOT_TRANSLATION, ROOT_ROTATION or JOINT_ROTATION.
    param_part : ndarray of int, shape (n_params,)
    param_axis : ndarray, shape (n_params, 3)
        Unit axis in the part frame (translation axis in world for the root).
    lower, upper : ndarray, shape (n_params,)
        Limits, radians for rotations (±inf for the root).
    affects : ndarray of bool, shape (n_parts, n_params)
        ``affects[p, k]``: parameter k moves part p (k acts on p or an ancestor).
    joint_names, joint_part : tuple of str, ndarray of int, shape (n_joints,)
    joint_point : ndarray, shape (n_joints, 3)
        Joint centre in its part's frame, metres.
    segments, width_parts, radius_groups : mapping str -> int, mapping str -> tuple of int, tuple of str
        Names ``load_model``'s ``segment_lengths``, ``widths`` and ``radius_scale`` may set (-> parts).
    """

    name: str
    height_m: float
    part_names: tuple
    parent: np.ndarray
    offset: np.ndarray
    rest_rotation: np.ndarray
    cones: np.ndarray
    param_names: tuple
    param_kind: np.ndarray
    param_part: np.ndarray
    param_axis: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    affects: np.ndarray
    joint_names: tuple
    joint_part: np.ndarray
    joint_point: np.ndarray
    segments: Mapping[str, int]
    width_parts: Mapping[str, tuple] = ()
    radius_groups: tuple = ()

    @property
    def n_parts(self) -> int:
        return len(self.part_names)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def dof(self) -> int:
        return self.n_params

    def part_index(self, name: str) -> int:
        """Index of a part by name; KeyError naming the model when absent."""
        try:
            return self.part_names.index(name)
        except ValueError:
            raise KeyError(f"model {self.name!r} has no part {name!r}") from None

    def pivots(self, names) -> tuple[np.ndarray, np.ndarray]:
        """Where the limbs below the joints ``names`` turn: each joint's ``PIVOT_PART`` origin where
        one is named and the model has that part, else its reported joint centre.

        Returns
        -------
        part : ndarray of int, shape (n,)
        point : ndarray, shape (n, 3)
            Metres in the part's frame.
        """
        part, point = [], []
        for name in names:
            pivot = PIVOT_PART.get(name)
            if pivot in self.part_names:
                part.append(self.part_index(pivot)), point.append(np.zeros(3))
            else:
                j = self.joint_names.index(name)
                part.append(self.joint_part[j]), point.append(self.joint_point[j])
        return np.asarray(part, dtype=int), np.asarray(point, dtype=float).reshape(-1, 3)

    def param_index(self, name: str) -> int:
        """Index of a parameter (``"<part>.<dof>"``) by name; KeyError naming the model when absent."""
        try:
            return self.param_names.index(name)
        except ValueError:
            raise KeyError(f"model {self.name!r} has no parameter {name!r}") from None

    def zero(self) -> np.ndarray:
        """The reference pose Φ = 0, shape (n_params,)."""
        return np.zeros(self.n_params)

    def clamp(self, params: np.ndarray) -> np.ndarray:
        """Project parameters onto the joint limits.

        Parameters
        ----------
        params : ndarray, shape (..., n_params)

        Returns
        -------
        ndarray, shape (..., n_params)
        """
        return np.clip(params, self.lower, self.upper)

    def within_limits(self, params: np.ndarray, *, tol: float = 1e-9) -> np.ndarray:
        """Whether parameters are within the joint limits.

        Parameters
        ----------
        params : ndarray, shape (..., n_params)
        tol : float
            Slack, in the parameters' units (radians, metres).

        Returns
        -------
        ndarray of bool, shape (...)
        """
        return np.all((params >= self.lower - tol) & (params <= self.upper + tol), axis=-1)

    def random_params(self, rng: np.random.Generator, *, fraction: float = 1.0) -> np.ndarray:
        """A random pose within ``fraction`` of each joint's range (root: ±1 m, any heading, small tilt).

        Parameters
        ----------
        rng : numpy.random.Generator
        fraction : float
            Share of each joint's range around its middle.

        Returns
        -------
        ndarray, shape (n_params,)
        """
        finite = np.isfinite(self.lower)
        lo, hi = np.where(finite, self.lower, 0.0), np.where(finite, self.upper, 0.0)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo) * fraction
        p = rng.uniform(mid - half, mid + half)
        # keep 0 (the reference) inside the sampled range for every joint
        p = np.where(finite, np.clip(p, lo, hi), 0.0)
        root_t = self.param_kind == ROOT_TRANSLATION
        p[root_t] = rng.uniform(-1, 1, root_t.sum()) * np.array([1.0, 1.0, 0.05])
        # any heading, a small tilt: a person standing somewhere in the volume
        p[self.param_kind == ROOT_ROTATION] = [rng.normal(0, 0.15), rng.normal(0, 0.15), rng.uniform(-np.pi, np.pi)]
        return p

    def with_height(self, height_m: float, *, segment_lengths: Mapping[str, float] | None = None,
                    widths: Mapping[str, float] | None = None,
                    radius_scale: Mapping[str, float] | None = None) -> "BodyModel":
        """The same model sized for another subject.

        Parameters
        ----------
        height_m : float
            Subject height, metres.
        segment_lengths, widths, radius_scale : mapping str -> float, optional
            Explicit segment lengths and widths (metres) and radius factors (``load_model``).

        Returns
        -------
        BodyModel
        """
        return load_model(self.name, height_m=height_m, segment_lengths=segment_lengths, widths=widths,
                          radius_scale=radius_scale)


def available_models() -> list[str]:
    """Names of the bundled model files (``tracker/body/models/*.toml``)."""
    return sorted(p.stem for p in MODELS_DIR.glob("*.toml"))


def load_model(
    name_or_path: str | Path = "knossow40",
    *,
    height_m: float | None = None,
    segment_lengths: Mapping[str, float] | None = None,
    widths: Mapping[str, float] | None = None,
    radius_scale: Mapping[str, float] | None = None,
) -> BodyModel:
    """Load a body model by name (``knossow40``, ``knossow54``) or file path and size it.

    Parameters
    ----------
    name_or_path : str or Path
        A bundled model's name, or a model TOML file.
    height_m : float, optional
        Subject height in metres (default ``DEFAULT_HEIGHT_M``); every length scales with it.
    segment_lengths : mapping str -> float, optional
        Explicit lengths in metres for named segments (the model file's ``segment`` keys, e.g.
        ``upper_arm``, ``thigh``), overriding the anthropometric ratios along that segment's axis.
    widths : mapping str -> float, optional
        Explicit left-right widths in metres (the model file's ``width`` keys: ``hip_width`` between
        the hip joint centres, ``shoulder_width`` between the shoulder joint centres).
    radius_scale : mapping str -> float, optional
        Factors on the cone radii of the named radius groups (``radius``, ``radius_a``, ``radius_b``
        keys: ``thigh``, ``shank``, ``upper_arm``, ``forearm``, ``trunk_width``, ``trunk_depth``).

    Returns
    -------
    BodyModel

    Raises
    ------
    ModelError
        Unknown model, malformed file (named), or a height outside 0.5-2.6 m.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = MODELS_DIR / f"{name_or_path}.toml"
        if not path.exists():
            raise ModelError(f"unknown body model {str(name_or_path)!r}; available: {', '.join(available_models())}")
    data = load_file(path, error=ModelError, what="model file")
    height = DEFAULT_HEIGHT_M if height_m is None else float(height_m)
    if not (0.5 <= height <= 2.6):
        raise ModelError(f"height_m must be between 0.5 and 2.6 m, got {height_m}")
    return _build(path, data, height, dict(segment_lengths or {}), dict(widths or {}), dict(radius_scale or {}))


def _build(path: Path, data: dict, H: float, segment_lengths: dict, widths: dict, radius_scale: dict) -> BodyModel:
    meta = data.get("model", {})
    name = str(meta.get("name", path.stem))
    parts = data.get("part")
    if not isinstance(parts, list) or not parts:
        raise ModelError(f"{path}: no [[part]] entries")
    names: list[str] = []
    parent, offset, rest, cones, axial_scale = [], [], [], [], []
    p_names, p_kind, p_part, p_axis, lower, upper = [], [], [], [], [], []
    segments: dict[str, int] = {}
    width_parts: dict[str, list[int]] = {}
    radius_groups: set[str] = set()
    for i, part in enumerate(parts):
        if not isinstance(part, dict):
            raise ModelError(f"{path}: [[part]] #{i} must be a table, got {part!r}")
        pname = str(part.get("name", f"#{i}"))
        where = f"{path}: part {pname!r}"
        if pname in names:
            raise ModelError(f"{where}: duplicate part name")
        par = str(part.get("parent", ""))
        joint = str(part.get("joint", "rotational"))
        if i == 0:
            if par or joint != "free":
                raise ModelError(f"{where}: the first part must be the root (no parent, joint = \"free\")")
            pidx = -1
        else:
            if joint == "free":
                raise ModelError(f"{where}: only the root part may have a free joint")
            if par not in names:
                raise ModelError(f"{where}: parent {par!r} is not a part defined before it")
            pidx = names.index(par)
        try:
            off = np.asarray(part.get("offset", [0, 0, 0]), dtype=float).reshape(3)
            rot = euler_xyz_deg(np.asarray(part.get("rotation", [0, 0, 0]), dtype=float).reshape(3))
            cone = part["cone"]
            a, b, k, z1, z2 = (float(cone[key]) for key in ("a", "b", "k", "z1", "z2"))
        except KeyError as exc:
            raise ModelError(f"{where}: missing key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ModelError(f"{where}: bad value: {exc}") from None
        if a <= 0 or b <= 0 or not z1 < z2:
            raise ModelError(f"{where}: cone needs a > 0, b > 0 and z1 < z2")
        if min(1 + k * z1, 1 + k * z2) <= 0.05:
            raise ModelError(f"{where}: cone taper k={k} puts the apex inside [z1, z2]")
        seg = part.get("segment")
        s_ax = 1.0
        if seg is not None:
            segments[str(seg)] = i
            if seg in segment_lengths:
                nominal = float(part.get("length", z2)) * H
                given = float(segment_lengths[seg])
                if not (0.2 * nominal <= given <= 3.0 * nominal):
                    raise ModelError(f"{where}: segment length {seg}={given} m is implausible (nominal {nominal:.3f} m)")
                s_ax = given / nominal
        wname = part.get("width")
        if wname is not None:
            if i == 0:
                raise ModelError(f"{where}: the root part cannot carry a width")
            width_parts.setdefault(str(wname), []).append(i)
        r_fac = []
        for key in ("radius_a", "radius_b"):
            group = part.get(key, part.get("radius"))
            if group is None:
                r_fac.append(1.0)
                continue
            radius_groups.add(str(group))
            fac = float(radius_scale.get(str(group), 1.0))
            if not 0.4 <= fac <= 2.5:
                raise ModelError(f"{where}: radius factor {group}={fac} is implausible (0.4-2.5)")
            r_fac.append(fac)
        names.append(pname)
        parent.append(pidx)
        offset.append(off * H)
        rest.append(rot)
        axial_scale.append(s_ax)
        cones.append([a * H * r_fac[0], b * H * r_fac[1], k / (H * s_ax), z1 * H * s_ax, z2 * H * s_ax])
        if joint == "free":
            for ax, n in zip("xyz", ("tx", "ty", "tz")):
                p_names.append(f"{pname}.{n}"), p_kind.append(ROOT_TRANSLATION), p_part.append(i)
                p_axis.append(_AXES[ax]), lower.append(-np.inf), upper.append(np.inf)
            for ax, n in zip("xyz", ("rx", "ry", "rz")):
                p_names.append(f"{pname}.{n}"), p_kind.append(ROOT_ROTATION), p_part.append(i)
                p_axis.append(_AXES[ax]), lower.append(-np.inf), upper.append(np.inf)
            continue
        dofs = part.get("dofs", [])
        if not isinstance(dofs, list) or not all(isinstance(d, dict) for d in dofs):
            raise ModelError(f"{where}: key 'dofs' must be a list of {{name, axis, limits}} tables")
        if len(dofs) > 3:
            raise ModelError(f"{where}: a joint has at most 3 rotational DOF, got {len(dofs)}")
        for d in dofs:
            dname = str(d.get("name", "?"))
            axis = str(d.get("axis", ""))
            if axis not in _AXES:
                raise ModelError(f"{where}: DOF {dname!r} has unknown axis {axis!r} (use x, y, z, -x, -y, -z)")
            lim = d.get("limits")
            try:
                lo, hi = (float(v) for v in lim)
            except (TypeError, ValueError):
                raise ModelError(f"{where}: DOF {dname!r} needs limits = [lo, hi] in degrees") from None
            if not (-360 <= lo < hi <= 360) or not (lo <= 0 <= hi):
                raise ModelError(f"{where}: DOF {dname!r} has impossible limits [{lo}, {hi}] (need -360 <= lo <= 0 <= hi <= 360, lo < hi)")
            p_names.append(f"{pname}.{dname}"), p_kind.append(JOINT_ROTATION), p_part.append(i)
            p_axis.append(_AXES[axis]), lower.append(np.radians(lo)), upper.append(np.radians(hi))
    # explicit segment lengths stretch the children's offsets along the parent's axis
    offset_arr = np.array(offset)
    for i, pidx in enumerate(parent):
        if pidx >= 0 and axial_scale[pidx] != 1.0:
            offset_arr[i, 2] *= axial_scale[pidx]
    unknown = set(segment_lengths) - set(segments)
    if unknown:
        raise ModelError(f"{path}: unknown segment(s) {sorted(unknown)}; known: {sorted(segments)}")
    for kind, given, known in (("width", widths, width_parts), ("radius group", radius_scale, radius_groups)):
        if set(given) - set(known):
            raise ModelError(f"{path}: unknown {kind}(s) {sorted(set(given) - set(known))}; known: {sorted(known)}")
    if widths:
        _apply_widths(path, offset_arr, rest, parent, width_parts, widths)
    n_parts = len(names)
    param_part = np.array(p_part)
    # ancestry: affects[p, k] if param k's part is p or an ancestor of p
    anc = np.eye(n_parts, dtype=bool)
    for i, pidx in enumerate(parent):
        if pidx >= 0:
            anc[i] |= anc[pidx]
    affects = anc[:, param_part]
    joints = data.get("joints", {})
    if not isinstance(joints, dict) or not all(isinstance(v, dict) for v in joints.values()):
        raise ModelError(f"{path}: [joints] must map joint names to {{part, point}} tables")
    j_names, j_part, j_point = [], [], []
    for jn in JOINT_NAMES:
        if jn not in joints:
            raise ModelError(f"{path}: [joints] lacks {jn!r}")
    for jn, spec in joints.items():
        part = str(spec.get("part", ""))
        if part not in names:
            raise ModelError(f"{path}: joint {jn!r} refers to unknown part {part!r}")
        pi = names.index(part)
        pt = np.asarray(spec.get("point", [0, 0, 0]), dtype=float).reshape(3) * H
        pt[2] *= axial_scale[pi]
        j_names.append(jn), j_part.append(pi), j_point.append(pt)

    def ro(x, dtype=float):
        arr = np.array(x, dtype=dtype)
        arr.setflags(write=False)
        return arr

    return BodyModel(
        name=name, height_m=H, part_names=tuple(names), parent=ro(parent, int), offset=ro(offset_arr),
        rest_rotation=ro(rest), cones=ro(cones), param_names=tuple(p_names), param_kind=ro(p_kind, int),
        param_part=ro(param_part, int), param_axis=ro(p_axis), lower=ro(lower), upper=ro(upper),
        affects=ro(affects, bool), joint_names=tuple(j_names), joint_part=ro(j_part, int),
        joint_point=ro(j_point), segments=dict(segments),
        width_parts={k: tuple(v) for k, v in width_parts.items()}, radius_groups=tuple(sorted(radius_groups)),
    )  # fmt: skip


def _apply_widths(path: Path, offset: np.ndarray, rest: list, parent: list, width_parts: dict, widths: dict) -> None:
    """Scale, in place, the lateral component (world y at the reference pose) of the offsets of the
    parts carrying each given width (``load_model``'s ``widths``) so that their origins lie
    ± width / 2 from the midline."""
    n = len(parent)
    R = np.zeros((n, 3, 3))
    P = np.zeros((n, 3))
    for i, pi in enumerate(parent):
        R[i] = rest[i] if pi < 0 else R[pi] @ rest[i]
        P[i] = offset[i] if pi < 0 else P[pi] + R[pi] @ offset[i]
    for wname, idx in width_parts.items():
        if wname not in widths:
            continue
        given = float(widths[wname])
        for i in idx:
            base = abs(P[parent[i], 1])
            reach = abs(P[i, 1]) - base
            if reach <= 1e-6:
                raise ModelError(f"{path}: width {wname!r}: part #{i} does not lie further out than its parent")
            s = (0.5 * given - base) / reach
            if not 0.3 <= s <= 3.0:
                raise ModelError(f"{path}: width {wname}={given} m is implausible for this model")
            lateral = R[parent[i]][1]  # world y in the parent's frame
            offset[i] += (s - 1.0) * (offset[i] @ lateral) * lateral
