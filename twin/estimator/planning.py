"""Measurement planning: choose N robot configurations that the stereo camera can see and that identify the
parameters well, and predict the calibration accuracy of the plan against random choice.

1. **Candidates** per station: plate poses sampled where the camera looks (plate centre uniform over the
   left image within a margin, depth in a range, plate normal within ``max_tilt`` of the direction to the
   cameras, any roll), turned into joint configurations by the nominal model's closed-form inverse (every
   branch inside the joint limits).
2. **Visibility** of a candidate: all three spheres (their whole image discs plus ``margin_px``) inside both
   images, in front of both cameras (:func:`twin.camera.spheres_in_view`); the plate normal within ``max_tilt`` of the direction to each camera;
   no line of sight from a camera centre to a sphere passes within ``link_radius + sphere radius`` of a
   link segment of the nominal model (frame origins 0..6: capsules, a coarse self-occlusion model).
3. **Design**: the whitened sphere-centre Jacobian of every candidate at the nominal model (stations at
   their approximate ``base2meas``), restricted to the parameters the whole pool identifies (the structural
   couplings are dropped, as the estimator does); greedy D-optimal selection (maximise
   ``log det(sum_k A_k^T A_k)`` over column-scaled blocks ``A_k``, a rank-9 update per step), then
   Fedorov-type exchange passes that swap a chosen configuration for a candidate while the determinant grows.
4. **Predicted accuracy**: the covariance ``(sum A^T A)^-1`` of the plan gives the RMS error of the
   calibrated model's sphere predictions over the whole visible pool (the Cramér-Rao floor of a correctly
   specified model at the stated noise); the same for random plans of N drawn from the pool.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..camera import CameraIntrinsics, spheres_in_view
from ..dataset import Plate
from ..kinematics import (
    RobotModel,
    inverse_kinematics_closed_form,
    link_frames,
    tool2base,
)
from ..transforms import invert_transform, make_transform, rotvec_to_matrix
from ..units import M_PER_MM, deg_to_rad
from .chain import Chain
from .identifiability import analyse_jacobian, preference_order
from .problem import ParamSpace, predict_points

__all__ = [
    "StereoCamera",
    "PlanOptions",
    "PlanResult",
    "visibility",
    "candidate_pool",
    "plan_measurements",
    "design_floor",
]


@dataclass(frozen=True, eq=False)
class StereoCamera:
    """Two pinhole cameras (OpenCV frames): ``left2right`` ``(4, 4)`` maps left-camera points into the right
    camera frame. The measurement frame of a station is the left camera frame."""

    left: CameraIntrinsics
    right: CameraIntrinsics
    left2right: np.ndarray

    @classmethod
    def from_json_dict(cls, d: dict, where: str = "camera file") -> "StereoCamera":
        """From the instrument's ``stereo_calibration.json`` (``kind = "stereo_calibration"``) or a hand-written
        ``kind = "stereo_camera"`` with the same fields: ``image_width``, ``image_height``, ``left`` and
        ``right`` (``fx_px, fy_px, cx_px, cy_px``, optional ``dist`` ``[k1, k2, p1, p2, k3]``) and
        ``left2right`` (``R`` 3x3, ``t_mm``)."""
        kind = d.get("kind")
        if kind not in ("stereo_calibration", "stereo_camera"):
            raise ValueError(f"{where}: field 'kind' must be 'stereo_calibration' or 'stereo_camera', got {kind!r}")
        try:
            w, h = int(d["image_width"]), int(d["image_height"])

            def cam(c):
                return CameraIntrinsics(float(c["fx_px"]), float(c["fy_px"]), float(c["cx_px"]), float(c["cy_px"]), w, h,
                                        tuple(float(x) for x in c.get("dist", [0, 0, 0, 0, 0])))

            T = np.eye(4)
            T[:3, :3] = np.asarray(d["left2right"]["R"], dtype=float)
            T[:3, 3] = np.asarray(d["left2right"]["t_mm"], dtype=float) * M_PER_MM
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{where}: missing or malformed field ({exc})") from None
        if np.abs(T[:3, :3] @ T[:3, :3].T - np.eye(3)).max() > 1e-6:
            raise ValueError(f"{where}: left2right.R is not a rotation matrix")
        return cls(cam(d["left"]), cam(d["right"]), T)


@dataclass(frozen=True)
class PlanOptions:
    """Visibility and sampling settings (SI): ``margin_px`` around each sphere's image disc, ``max_tilt``
    [rad] between plate normal and the direction to a camera, ``link_radius`` [m] of the occlusion capsules,
    ``depth`` ``(min, max)`` [m] of the plate centre from the left camera (None: +-15 % around the distance
    at which the two optical axes cross, else 0.55-0.85 m)."""

    margin_px: float = 20.0
    max_tilt: float = deg_to_rad(55.0)
    link_radius: float = 0.045
    depth: tuple[float, float] | None = None


@dataclass(frozen=True)
class PlanResult:
    """``q`` ``(n, N)`` and ``station`` ``(n,)`` of the plan, in measurement order; ``floor_plan``
    [m] predicted RMS sphere-prediction error of the plan, ``floor_random`` ``(R,)`` [m] the same for random
    plans (``inf`` when a random plan cannot identify the parameters); design numbers (``logdet``, ``O1``,
    condition number) for the plan and the random plans' median; pool sizes per station; identifiable
    parameters; the greedy/exchange trace."""

    q: np.ndarray
    station: np.ndarray
    floor_plan: float
    floor_random: np.ndarray
    design: dict[str, Any]
    pool: dict[str, int]
    identifiable: tuple[str, ...]
    dropped: tuple[str, ...]
    trace: tuple[dict, ...] = field(default_factory=tuple)


# ------------------------------------------------------------------------------------------------
# Visibility
# ------------------------------------------------------------------------------------------------

def _seg_seg_distance(p0, p1, q0, q1) -> np.ndarray:
    """Minimum distance between segments ``[p0, p1]`` and ``[q0, q1]`` (broadcast over leading axes)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    den = a * e - b * b
    a_s = np.maximum(a, 1e-300)
    e_s = np.maximum(e, 1e-300)
    s = np.where(den > 1e-18, np.clip((b * f - c * e) / np.maximum(den, 1e-300), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_s
    t_c = np.clip(t, 0.0, 1.0)
    s = np.where(t < 0, np.clip(-c / a_s, 0, 1), np.where(t > 1, np.clip((b - c) / a_s, 0, 1), s))
    t = t_c
    cp = p0 + s[..., None] * d1
    cq = q0 + t[..., None] * d2
    return np.linalg.norm(cp - cq, axis=-1)


def visibility(
    model: RobotModel,
    q: np.ndarray,
    base2meas: np.ndarray,
    camera: StereoCamera,
    plate: Plate,
    options: PlanOptions = PlanOptions(),
) -> tuple[np.ndarray, np.ndarray]:
    """Which configurations ``q`` ``(n, N)`` the rig at ``base2meas`` sees (see the module docstring).

    Returns ``(visible (n,), reason (n,))`` with reason codes ``""`` (visible), ``"limits"``, ``"image"``,
    ``"tilt"``, ``"occluded"`` (the first failed test).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n = q.shape[0]
    Tinv = invert_transform(model.tool2flange)
    s_tool = plate.spheres_flange @ Tinv[:3, :3].T + Tinv[:3, 3]
    r_s = 0.5 * plate.sphere_diameter
    T = base2meas @ tool2base(model, q)  # tool2meas (n, 4, 4)
    S = np.einsum("nij,kj->nki", T[:, :3, :3], s_tool) + T[:, None, :3, 3]  # (n, K, 3) left-camera frame
    reason = np.full(n, "", dtype=object)
    reason[~model.within_limits(q)] = "limits"
    L2R = camera.left2right
    cams = [(np.eye(4), camera.left), (L2R, camera.right)]
    centres = [np.zeros(3), invert_transform(L2R)[:3, 3]]
    ok_img = np.ones(n, dtype=bool)
    for (Tc, intr) in cams:
        P = S @ Tc[:3, :3].T + Tc[:3, 3]
        ok_img &= spheres_in_view(P, intr, radius=r_s, margin_px=options.margin_px, min_depth=0.05)
    reason[(reason == "") & ~ok_img] = "image"
    normal = T[:, :3, 2]
    centre = S.mean(axis=1)
    ok_tilt = np.ones(n, dtype=bool)
    for c in centres:
        v = c - centre
        cosang = np.sum(v * normal, -1) / np.linalg.norm(v, axis=-1)
        ok_tilt &= cosang >= np.cos(options.max_tilt)
    reason[(reason == "") & ~ok_tilt] = "tilt"
    todo = np.flatnonzero(reason == "")
    if todo.size:
        F = link_frames(model.with_frames(base2meas=base2meas), q[todo], frame="meas")[:, :, :3, 3]  # (m, N+1, 3)
        seg0, seg1 = F[:, :-1], F[:, 1:]  # (m, N, 3)
        occl = np.zeros(todo.size, dtype=bool)
        for c in centres:
            a0 = np.broadcast_to(c, S[todo].shape)[:, :, None, :]  # (m, 3, 1, 3)
            a1 = S[todo][:, :, None, :]
            dist = _seg_seg_distance(a0, a1, seg0[:, None], seg1[:, None])  # (m, 3, 6)
            occl |= np.any(dist < options.link_radius + r_s, axis=(1, 2))
        reason[todo[occl]] = "occluded"
    return reason == "", reason


def _default_depth(camera: StereoCamera) -> tuple[float, float]:
    """+-15 % around where the optical axes cross (the rig's stand-off), else 0.55-0.85 m."""
    R, t = camera.left2right[:3, :3], camera.left2right[:3, 3]
    # right optical axis in the left frame: points c + s d; left axis: (0, 0, z)
    c = -R.T @ t
    d = R.T @ np.array([0.0, 0.0, 1.0])
    # closest approach of the two axes
    A = np.array([[1.0, -d[2]], [d[2], -d @ d]])
    try:
        z, s = np.linalg.solve(A, np.array([c[2], c @ d]))
    except np.linalg.LinAlgError:
        return 0.55, 0.85
    if not (0.2 < z < 5.0):
        return 0.55, 0.85
    return 0.85 * z, 1.15 * z


def candidate_pool(
    model: RobotModel,
    base2meas: np.ndarray,
    camera: StereoCamera,
    plate: Plate,
    n: int,
    rng: np.random.Generator,
    options: PlanOptions = PlanOptions(),
    max_rounds: int = 40,
) -> np.ndarray:
    """About ``n`` visible configurations ``(m, N)`` for one station (see the module docstring). A chain without a
    closed-form inverse (not a 6R arm with a spherical wrist) is sampled uniformly inside its joint limits
    instead, keeping what the rig sees."""
    try:
        inverse_kinematics_closed_form(model, np.eye(4)[None])
    except ValueError:
        return _joint_space_pool(model, base2meas, camera, plate, n, rng, options, max_rounds)
    intr = camera.left
    dmin, dmax = options.depth if options.depth is not None else _default_depth(camera)
    Tinv = invert_transform(model.tool2flange)
    s_tool = plate.spheres_flange @ Tinv[:3, :3].T + Tinv[:3, 3]
    centroid = s_tool.mean(axis=0)
    meas2base = invert_transform(base2meas)
    out: list[np.ndarray] = []
    total = 0
    for _ in range(max_rounds):
        k = max(200, 2 * (n - total))
        u = rng.uniform(options.margin_px, intr.width - options.margin_px, k)
        v = rng.uniform(options.margin_px, intr.height - options.margin_px, k)
        z = rng.uniform(dmin, dmax, k)
        p = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
        # plate normal towards the camera, tilted by up to max_tilt about a random axis, any roll about it
        n0 = -p / np.linalg.norm(p, axis=1, keepdims=True)
        ax = rng.normal(size=(k, 3))
        ax -= np.sum(ax * n0, 1, keepdims=True) * n0
        ax /= np.linalg.norm(ax, axis=1, keepdims=True)
        tilt = options.max_tilt * np.sqrt(rng.uniform(0, 1, k))
        nrm = np.einsum("nij,nj->ni", rotvec_to_matrix(ax * tilt[:, None]), n0)
        # frame with z = normal, random roll
        ref = np.where(np.abs(nrm[:, [0]]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
        x = np.cross(ref, nrm)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        y = np.cross(nrm, x)
        R = np.stack([x, y, nrm], axis=2)
        R = R @ rotvec_to_matrix(np.c_[np.zeros((k, 2)), rng.uniform(-np.pi, np.pi, k)])
        t = p - np.einsum("nij,j->ni", R, centroid)
        tool2meas = make_transform(R, t)
        flange2base = meas2base @ tool2meas @ Tinv
        sols = inverse_kinematics_closed_form(model, flange2base)
        qs = sols.q[sols.within_limits]
        if qs.size:
            vis, _ = visibility(model, qs, base2meas, camera, plate, options)
            out.append(qs[vis])
            total += int(vis.sum())
        if total >= n:
            break
    if not out or total == 0:
        return np.zeros((0, model.n_joints))
    q = np.concatenate(out)
    if q.shape[0] > n:
        q = q[rng.choice(q.shape[0], n, replace=False)]
    return q


def _joint_space_pool(model: RobotModel, base2meas: np.ndarray, camera: StereoCamera, plate: Plate, n: int,
                      rng: np.random.Generator, options: PlanOptions, max_rounds: int) -> np.ndarray:
    """Visible configurations ``(m, N)`` drawn uniformly inside the joint limits (at most +-pi)."""
    lo = np.maximum(model.q_min, -np.pi)
    hi = np.minimum(model.q_max, np.pi)
    out: list[np.ndarray] = []
    total = 0
    for _ in range(max_rounds):
        qs = rng.uniform(lo, hi, (max(500, 4 * (n - total)), model.n_joints))
        vis, _ = visibility(model, qs, base2meas, camera, plate, options)
        out.append(qs[vis])
        total += int(vis.sum())
        if total >= n:
            break
    q = np.concatenate(out) if out else np.zeros((0, model.n_joints))
    if q.shape[0] > n:
        q = q[rng.choice(q.shape[0], n, replace=False)]
    return q


# ------------------------------------------------------------------------------------------------
# Design
# ------------------------------------------------------------------------------------------------

def _blocks(space: ParamSpace, x: np.ndarray, q: np.ndarray, station: np.ndarray, s_tool: np.ndarray, sigma: float):
    """Whitened Jacobian blocks ``(m, 3K, P)`` of the K marker points of each candidate."""
    _, Jk = predict_points(space, x, q, station, s_tool, jacobian=True)  # (P, K, 3, m)
    return np.transpose(Jk, (3, 1, 2, 0)).reshape(q.shape[0], 3 * s_tool.shape[0], space.size) / sigma


def design_floor(A: np.ndarray, sel: np.ndarray, A_eval: np.ndarray) -> float:
    """Predicted RMS 3-D point-prediction error over the evaluation blocks ``A_eval`` ``(e, 3K, p)`` (in units
    of sigma) of the design ``sel`` (indices into ``A`` ``(m, 3K, p)``): ``inf`` if the design is singular."""
    M = np.einsum("kri,krj->ij", A[sel], A[sel])
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return float("inf")
    if np.min(np.diag(L)) ** 2 < 1e-12 * np.max(np.diag(M)):
        return float("inf")
    Z = np.linalg.solve(L, A_eval.reshape(-1, A_eval.shape[-1]).T)  # (p, 3K e)
    v = np.sum(Z**2, axis=0).reshape(-1, 3).sum(axis=-1)  # per point: summed over coordinates
    return float(np.sqrt(np.mean(v)))


def _logdet(M: np.ndarray) -> float:
    s, ld = np.linalg.slogdet(M)
    return float(ld) if s > 0 else -np.inf


def _greedy(A: np.ndarray, n: int, eps: float, trace: list) -> np.ndarray:
    m, r, p = A.shape
    M = eps * np.eye(p)
    chosen: list[int] = []
    avail = np.ones(m, dtype=bool)
    for step in range(n):
        Minv = np.linalg.inv(M)
        G = np.eye(r)[None] + np.einsum("kri,ij,ksj->krs", A, Minv, A)
        s, gain = np.linalg.slogdet(G)
        gain = np.where(avail & (s > 0), gain, -np.inf)
        k = int(np.argmax(gain))
        chosen.append(k)
        avail[k] = False
        M = M + A[k].T @ A[k]
        trace.append({"stage": "greedy", "step": step + 1, "logdet": _logdet(M)})
    return np.array(chosen, dtype=int)


def _exchange(A: np.ndarray, sel: np.ndarray, eps: float, passes: int, trace: list) -> np.ndarray:
    sel = sel.copy()
    p = A.shape[2]
    for ps in range(passes):
        improved = False
        for i in range(len(sel)):
            M = eps * np.eye(p) + np.einsum("kri,krj->ij", A[sel], A[sel])
            base = _logdet(M)
            Mi = M - A[sel[i]].T @ A[sel[i]]
            Minv = np.linalg.inv(Mi)
            G = np.eye(A.shape[1])[None] + np.einsum("kri,ij,ksj->krs", A, Minv, A)
            s, gain = np.linalg.slogdet(G)
            gain = np.where(s > 0, gain, -np.inf) + _logdet(Mi)
            gain[sel] = -np.inf
            k = int(np.argmax(gain))
            if gain[k] > base + 1e-9:
                sel[i] = k
                improved = True
        M = eps * np.eye(p) + np.einsum("kri,krj->ij", A[sel], A[sel])
        trace.append({"stage": "exchange", "pass": ps + 1, "logdet": _logdet(M)})
        if not improved:
            break
    return sel


def _order_for_measurement(q: np.ndarray, station_idx: np.ndarray) -> np.ndarray:
    """Group by station, then nearest-neighbour order in joint space (short robot motions)."""
    order = []
    for s in np.unique(station_idx):
        idx = list(np.flatnonzero(station_idx == s))
        cur = idx.pop(0)
        order.append(cur)
        while idx:
            d = [np.max(np.abs(q[j] - q[cur])) for j in idx]
            cur = idx.pop(int(np.argmin(d)))
            order.append(cur)
    return np.array(order, dtype=int)


def plan_measurements(
    model: RobotModel,
    stations: dict[str, np.ndarray],
    camera: StereoCamera,
    plate: Plate,
    n: int,
    *,
    pool_per_station: int = 600,
    noise_position: float = 1e-5,
    n_random: int = 30,
    exchange_passes: int = 2,
    seed: int = 0,
    options: PlanOptions = PlanOptions(),
    progress: Callable[[str], None] | None = None,
) -> PlanResult:
    """Choose ``n`` visible configurations over ``stations`` (``{name: approximate base2meas (4, 4)}``) for the
    nominal ``model``; see the module docstring. Raises ``ValueError`` when a station sees no configuration
    or the pool cannot identify the parameters."""
    if n < 1:
        raise ValueError(f"n must be a positive number of configurations, got {n!r}")
    if not stations:
        raise ValueError("stations: give at least one station's approximate base2meas")
    rng = np.random.default_rng(seed)
    names = tuple(stations)
    qs, st = [], []
    pool = {}
    for k, s in enumerate(names):
        qk = candidate_pool(model, np.asarray(stations[s], float), camera, plate, pool_per_station, rng, options)
        if qk.shape[0] == 0:
            raise ValueError(f"station {s!r}: the camera sees the plate in no reachable configuration "
                             "(check its base2meas, the camera model and the joint limits)")
        pool[s] = int(qk.shape[0])
        qs.append(qk)
        st.append(np.full(qk.shape[0], k))
        if progress:
            progress(f"station {s}: {qk.shape[0]} visible candidates")
    Q = np.concatenate(qs)
    S = np.concatenate(st)
    space = ParamSpace(Chain.of(model), names)
    x0 = space.from_model(model.with_frames(base2meas=np.eye(4)), {s: np.asarray(stations[s], float) for s in names})
    Tinv = invert_transform(model.tool2flange)
    s_tool = plate.spheres_flange @ Tinv[:3, :3].T + Tinv[:3, 3]
    Afull = _blocks(space, x0, Q, S, s_tool, noise_position)
    ida = analyse_jacobian(Afull.reshape(-1, space.size), space.names,
                           order=preference_order(space.names, "frames"))
    keep = np.array([space.index(nm) for nm in ida.identifiable])
    A = Afull[:, :, keep]
    m = A.shape[0]
    # column scaling: unit mean information per candidate (makes eps and the determinant well scaled)
    D = np.sqrt(m) / np.linalg.norm(A.reshape(-1, keep.size), axis=0)
    As = A * D
    if n > m:
        raise ValueError(f"n={n} exceeds the {m} visible candidates found; lower n or enlarge the pool")
    trace: list[dict] = []
    eps = 1e-6
    sel = _greedy(As, n, eps, trace)
    if exchange_passes:
        sel = _exchange(As, sel, eps, exchange_passes, trace)
    floor_plan = design_floor(A, sel, A)
    floors = []
    ld_rand = []
    for _ in range(n_random):
        r = rng.choice(m, n, replace=False)
        floors.append(design_floor(A, r, A))
        ld_rand.append(_logdet(np.einsum("kri,krj->ij", As[r], As[r])))

    def numbers(idx):
        J = As[idx].reshape(-1, keep.size)
        sv = np.linalg.svd(J / np.linalg.norm(J, axis=0), compute_uv=False)
        return {
            "logdet_scaled": _logdet(np.einsum("kri,krj->ij", As[idx], As[idx])),
            "condition_number": float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf"),
            "O1": float(np.exp(np.mean(np.log(np.maximum(sv, 1e-300)))) / np.sqrt(J.shape[0])),
        }

    design = {"plan": numbers(sel), "random_median_logdet_scaled": float(np.median(ld_rand))}
    order = _order_for_measurement(Q[sel], S[sel])
    sel = sel[order]
    return PlanResult(
        q=Q[sel],
        station=np.array([names[k] for k in S[sel]], dtype=object),
        floor_plan=floor_plan * noise_position,
        floor_random=np.array(floors) * noise_position,
        design=design,
        pool=pool,
        identifiable=tuple(ida.identifiable),
        dropped=tuple(ida.dropped),
        trace=tuple(trace),
    )
