"""Pose sampling for campaigns: configurations whose plate the station's cameras see.

Everything here plans with the *nominal* robot and the *nominal* camera placement, as an operator would:
a pose is accepted when every sphere of the plate, with its projected radius plus a margin, falls inside
every camera image of the station (:func:`twin.camera.spheres_in_view`) and the plate faces the cameras.
The world may still find a sphere hidden (the true robot differs by millimetres; a link may occlude);
the instrument then reports it and the campaign keeps the row with its status.

Three samplers, all seeded by the caller's ``numpy.random.Generator``:

* :func:`sample_configurations` -- random configurations inside the joint limits and the field of view:
  a plate centre uniformly on a random pixel ray of the reference camera at a random depth, the plate
  normal within ``max_tilt`` of the direction to the station, a uniform roll about it; the closed-form
  inverse (:func:`twin.kinematics.inverse_kinematics_closed_form`) of the nominal model gives the joints.
* :func:`sample_motion_pairs` -- the separation paper's motion pairs (its "beginning and end of the posture
  movement"): by default two independent configurations of the same station; with ``turn`` set, a local
  posture movement: the plate turns about its centre by an angle drawn uniformly in ``turn`` about a random
  axis and its centre shifts by a length drawn uniformly in ``shift`` along a random direction.
* :func:`sample_distance_moves` -- fixed-distance moves: a start configuration, a random direction, the
  plate centre moved by exactly ``distance``; the orientation kept (default) or turned about the plate
  centre by an angle drawn uniformly in ``distance_turn``; solved with the closed-form inverse on the
  branch nearest the start.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraIntrinsics, spheres_in_view
from ..dataset import Plate
from ..kinematics import (
    IKSolutions,
    RobotModel,
    flange2base,
    inverse_kinematics_closed_form,
    link_frames,
    wrap_angle,
)
from ..transforms import invert_transform, make_transform, rotvec_to_matrix
from ..instrument.plate import paper_frame_from_spheres
from ..units import MM_PER_M, deg_to_rad

__all__ = [
    "ViewCamera",
    "Station",
    "look_at_cam2base",
    "stereo_station",
    "SamplingOptions",
    "plate_in_view",
    "sample_configurations",
    "sample_motion_pairs",
    "sample_distance_moves",
    "SamplingError",
]


class SamplingError(ValueError):
    """No pose satisfying the constraints was found within the allowed number of attempts."""


@dataclass(frozen=True)
class ViewCamera:
    """A camera as the planner sees it: OpenCV ``cam2base`` ``(4, 4)`` (x right, y down, z forward) [m] and
    nominal intrinsics."""

    cam2base: np.ndarray
    intrinsics: CameraIntrinsics

    @property
    def base2cam(self) -> np.ndarray:
        return invert_transform(self.cam2base)


@dataclass(frozen=True)
class Station:
    """A placement of the camera rig: a name and its cameras (the first is the reference, the left one)."""

    name: str
    cameras: tuple[ViewCamera, ...]

    def __post_init__(self) -> None:
        if not self.cameras:
            raise ValueError(f"station {self.name!r}: cameras must not be empty")

    @property
    def centre(self) -> np.ndarray:
        """Mean camera position ``(3,)`` [m] in the base frame."""
        return np.mean([c.cam2base[:3, 3] for c in self.cameras], axis=0)


def look_at_cam2base(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV ``cam2base`` ``(4, 4)`` of a camera at ``eye`` [m] looking at ``target`` [m], image 'up' near ``up``."""
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    if np.linalg.norm(z) < 1e-9:
        raise ValueError(f"target must differ from eye, got {target!r}")
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))  # right = forward x up; OpenCV y = z x x then points down
    if np.linalg.norm(x) < 1e-9:
        raise ValueError(f"up {up!r} is parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_transform(np.stack([x, y, z], axis=1), eye)


def stereo_station(
    name: str, centre, target, baseline: float, intrinsics: CameraIntrinsics, up=(0.0, 0.0, 1.0)
) -> Station:
    """A converging stereo pair: cameras ``baseline`` [m] apart around ``centre`` [m], both aimed at ``target``."""
    if not (np.isfinite(baseline) and baseline > 0):
        raise ValueError(f"baseline must be positive [m], got {baseline!r}")
    mid = look_at_cam2base(centre, target, up)
    x = mid[:3, 0]
    left = look_at_cam2base(np.asarray(centre, float) - 0.5 * baseline * x, target, up)
    right = look_at_cam2base(np.asarray(centre, float) + 0.5 * baseline * x, target, up)
    return Station(name, (ViewCamera(left, intrinsics), ViewCamera(right, intrinsics)))


@dataclass(frozen=True)
class SamplingOptions:
    """Constraints of the samplers. Lengths [m], angles [rad], margins [px]."""

    depth_min: float = 0.6
    depth_max: float = 0.8
    max_tilt: float = deg_to_rad(35.0)
    margin_px: float = 20.0
    max_attempts: int = 20000
    q_home: np.ndarray = field(default_factory=lambda: deg_to_rad(np.array([0.0, 10.0, 10.0, 0.0, 45.0, 0.0])))
    branch: str = "random"  # 'random' among the in-limit branches, or 'home' (nearest q_home)
    min_q5: float = deg_to_rad(5.0)  # keep away from the wrist singularity (q5 = 0)
    min_link_height: float = 0.1  # [m] every joint origin from frame 2 on stays this far above the base plane
    # [rad] planned joints stay this far inside the limits, leaving room for the compensated command
    limit_margin: float = deg_to_rad(5.0)
    # |pitch| of the plate's ZYX Euler angles (eq. 43) in the base frame stays below this [rad]: at +-90 deg
    # the paper's Euler-angle-change statistic is singular (roll and yaw are undefined there)
    max_euler_pitch: float = deg_to_rad(60.0)
    # roll of the plate about its normal, from 'level' (plate x axis horizontal): uniform in [-max_roll, max_roll]
    max_roll: float = np.pi
    # motion pairs: (min, max) [rad] of the plate's turn about its centre between start and end (random axis,
    # angle uniform in the range); None = start and end are independent configurations
    turn: tuple[float, float] | None = None
    # motion pairs with `turn`: (min, max) [m] of the plate centre's shift (random direction, length uniform)
    shift: tuple[float, float] = (0.0, 0.0)
    # distance moves: (min, max) [rad] of the plate's turn about its centre during the move; (0, 0) keeps the
    # orientation
    distance_turn: tuple[float, float] = (0.0, 0.0)
    # [rad] no joint moves more than this between the start and the end of a local motion or a distance move
    max_joint_step: float = deg_to_rad(60.0)

    def __post_init__(self) -> None:
        if not (0 < self.depth_min <= self.depth_max):
            raise ValueError(f"depth_min/depth_max must satisfy 0 < min <= max [m], got {self.depth_min}, {self.depth_max}")
        if not (0 <= self.max_roll <= np.pi):
            raise ValueError(f"max_roll must be in [0, pi] [rad], got {self.max_roll}")
        if not (0 < self.max_euler_pitch <= np.pi / 2):
            raise ValueError(f"max_euler_pitch must be in (0, pi/2] [rad], got {self.max_euler_pitch}")
        if not (0 <= self.max_tilt < np.pi / 2):
            raise ValueError(f"max_tilt must be in [0, pi/2) [rad], got {self.max_tilt}")
        if self.branch not in ("random", "home"):
            raise ValueError(f"branch must be 'random' or 'home', got {self.branch!r}")
        if self.max_attempts < 1:
            raise ValueError(f"max_attempts must be >= 1, got {self.max_attempts}")
        for name, rng_, top in (("turn", self.turn, np.pi), ("shift", self.shift, np.inf),
                                ("distance_turn", self.distance_turn, np.pi)):
            if rng_ is None and name == "turn":
                continue
            if len(rng_) != 2 or not (0 <= rng_[0] <= rng_[1] <= top):
                raise ValueError(f"{name} must be (min, max) with 0 <= min <= max <= {top}, got {rng_!r}")
        if not (0 < self.max_joint_step <= 2 * np.pi):
            raise ValueError(f"max_joint_step must be in (0, 2 pi] [rad], got {self.max_joint_step}")


def _plate_centre_flange(plate: Plate) -> np.ndarray:
    """Plate frame (eq. 38-40) in the flange frame ``(4, 4)``, from the nominal sphere centres."""
    return paper_frame_from_spheres(plate.spheres_flange)


def plate_in_view(
    model: RobotModel, q: np.ndarray, station: Station, plate: Plate, options: SamplingOptions | None = None
) -> np.ndarray:
    """Mask ``(n,)``: every sphere inside every camera image (with its radius and the margin), in front of
    the cameras, the plate facing the station within ``max_tilt`` (plus 10 deg of slack), the plate
    centre within ``[depth_min, depth_max]`` of the reference camera (with 5 % slack), and no joint origin
    beyond the shoulder below ``min_link_height`` (the floor)."""
    opt = options or SamplingOptions()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    F = flange2base(model.with_frames(base2meas=np.eye(4)), q) @ model.tool2flange
    spheres = np.einsum("nij,mj->nmi", F[:, :3, :3], plate.spheres_flange) + F[:, None, :3, 3]  # (n, 3, 3)
    P = F @ _plate_centre_flange(plate)
    ok = np.ones(q.shape[0], dtype=bool)
    frames = link_frames(model, q, frame="base")  # (n, 7, 4, 4)
    ok &= np.all(frames[:, 2:, 2, 3] >= opt.min_link_height, axis=1)
    to_station = station.centre - P[:, :3, 3]
    to_station /= np.linalg.norm(to_station, axis=1, keepdims=True)
    ok &= np.einsum("ni,ni->n", P[:, :3, 2], to_station) >= np.cos(min(opt.max_tilt + deg_to_rad(10.0), np.pi / 2))
    ref = station.cameras[0]
    depth = (P[:, :3, 3] @ ref.base2cam[:3, :3].T + ref.base2cam[:3, 3])[:, 2]
    ok &= (depth >= 0.95 * opt.depth_min) & (depth <= 1.05 * opt.depth_max)
    r = 0.5 * plate.sphere_diameter
    for cam in station.cameras:
        pc = spheres.reshape(-1, 3) @ cam.base2cam[:3, :3].T + cam.base2cam[:3, 3]
        ok &= spheres_in_view(pc.reshape(-1, 3, 3), cam.intrinsics, radius=r, margin_px=opt.margin_px, min_depth=r * 2)
    return ok


def _euler_pitch_ok(model: RobotModel, q: np.ndarray, plate: Plate, opt: SamplingOptions) -> np.ndarray:
    """Mask ``(n,)``: the plate frame's ZYX pitch ``|ry| = |asin(-R[2, 0])|`` in the base frame is at most
    ``max_euler_pitch``."""
    F = flange2base(model.with_frames(base2meas=np.eye(4)), np.atleast_2d(q)) @ model.tool2flange @ _plate_centre_flange(plate)
    return np.abs(F[:, 2, 0]) <= np.sin(opt.max_euler_pitch) + 1e-12


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _frames_with_z(z: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` whose third column is ``z`` ``(n, 3)``, rolled by ``roll`` ``(n,)`` [rad] about it
    from 'level' (x axis horizontal, i.e. perpendicular to the base z axis; any x when ``z`` is vertical)."""
    x = np.stack([-z[:, 1], z[:, 0], np.zeros(len(z))], axis=1)  # e_z x z
    vertical = np.linalg.norm(x, axis=1) < 1e-6
    x[vertical] = np.stack([np.zeros(vertical.sum()), -z[vertical, 2], z[vertical, 1]], axis=1)  # e_x x z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    c, s_ = np.cos(roll)[:, None], np.sin(roll)[:, None]
    return np.stack([c * x + s_ * y, -s_ * x + c * y, z], axis=2)


def _pick_branches(
    sol: IKSolutions, rng: np.random.Generator, opt: SamplingOptions, q_ref: np.ndarray | None, model: RobotModel
) -> tuple[np.ndarray, np.ndarray]:
    """Per target: a branch ``limit_margin`` inside the limits and away from the wrist singularity, chosen at random, or the
    one nearest ``q_ref`` ``(6,)`` (or ``q_home`` when ``branch == 'home'``). Returns ``(q (n, 6), found (n,))``."""
    inner = np.all((sol.q >= model.q_min + opt.limit_margin) & (sol.q <= model.q_max - opt.limit_margin), axis=-1)
    ok = sol.within_limits & inner & (np.abs(sol.q[..., 4]) >= opt.min_q5)  # (n, 8)
    n = ok.shape[0]
    if q_ref is not None or opt.branch == "home":
        ref = q_ref if q_ref is not None else opt.q_home
        score = np.linalg.norm(wrap_angle(sol.q - ref), axis=-1)
    else:
        score = rng.random(ok.shape)
    score = np.where(ok, score, np.inf)
    best = np.argmin(score, axis=1)
    return sol.q[np.arange(n), best], ok.any(axis=1)


def _flange_model(model: RobotModel) -> RobotModel:
    return model.with_frames(base2meas=np.eye(4), tool2flange=np.eye(4))


def _candidate_targets(
    model: RobotModel, station: Station, plate: Plate, m: int, rng: np.random.Generator, opt: SamplingOptions
) -> np.ndarray:
    """``m`` flange targets ``(m, 4, 4)`` putting the plate centre on a random pixel ray at a random depth,
    facing the station within ``max_tilt``, with a random roll."""
    ref = station.cameras[0]
    K = ref.intrinsics
    u = rng.uniform(opt.margin_px, K.width - 1 - opt.margin_px, m)
    v = rng.uniform(opt.margin_px, K.height - 1 - opt.margin_px, m)
    depth = rng.uniform(opt.depth_min, opt.depth_max, m)
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(m)], axis=1) * depth[:, None]
    centre = rays @ ref.cam2base[:3, :3].T + ref.cam2base[:3, 3]
    normal = station.centre - centre
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # plate normal uniformly on the spherical cap of half-angle max_tilt around the direction to the station
    cos_t = rng.uniform(np.cos(opt.max_tilt), 1.0, m)
    axis = np.cross(normal, _random_unit(rng, m))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    z = np.einsum("nij,nj->ni", rotvec_to_matrix(axis * np.arccos(cos_t)[:, None]), normal)
    roll = rng.uniform(-opt.max_roll, opt.max_roll, m)
    R = _frames_with_z(z, roll)
    plate2base = make_transform(R, centre)
    plate2flange = model.tool2flange @ _plate_centre_flange(plate)
    return plate2base @ invert_transform(plate2flange)


def sample_configurations(
    model: RobotModel,
    station: Station,
    plate: Plate,
    n: int,
    rng: np.random.Generator,
    options: SamplingOptions | None = None,
    batch: int | None = None,
    q_ref: np.ndarray | None = None,
) -> np.ndarray:
    """``n`` commanded configurations ``(n, 6)`` [rad] in the joint limits with the plate in view of ``station``.

    With ``q_ref`` ``(6,)`` the inverse-kinematics branch nearest ``q_ref`` is taken (a motion that stays on
    the arm's current branch); otherwise per ``options.branch``.

    Candidates are drawn ``batch`` at a time (:func:`_candidate_targets`), solved with the closed-form inverse
    of the nominal model and kept in order when :func:`plate_in_view`. Raises :class:`SamplingError` when
    ``max_attempts`` candidates did not give ``n`` poses.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    opt = options or SamplingOptions()
    fm = _flange_model(model)
    out: list[np.ndarray] = []
    attempts = 0
    while len(out) < n:
        if attempts >= opt.max_attempts:
            raise SamplingError(
                f"found only {len(out)} of {n} configurations for station {station.name!r} in {opt.max_attempts} "
                "attempts: check the station placement, depth range and joint limits"
            )
        m = min(batch or max(16, min(64, 4 * (n - len(out)))), opt.max_attempts - attempts)
        attempts += m
        targets = _candidate_targets(model, station, plate, m, rng, opt)
        q, found = _pick_branches(inverse_kinematics_closed_form(fm, targets), rng, opt, q_ref, model)
        good = found & plate_in_view(model, q, station, plate, opt) & _euler_pitch_ok(model, q, plate, opt)
        out.extend(q[good][: n - len(out)])
    return np.array(out).reshape(n, 6)


def sample_motion_pairs(
    model: RobotModel,
    station: Station,
    plate: Plate,
    n_pairs: int,
    rng: np.random.Generator,
    options: SamplingOptions | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(q_start, q_end)``, each ``(n_pairs, 6)`` [rad]: a random in-view start and a random in-view end
    reached on the start's inverse-kinematics branch (the arm moves to another posture without flipping its
    shoulder, elbow or wrist)."""
    opt = options or SamplingOptions()
    if opt.turn is not None:
        return _local_motions(model, station, plate, n_pairs, rng, opt)
    starts = sample_configurations(model, station, plate, n_pairs, rng, options)
    ends = np.array([sample_configurations(model, station, plate, 1, rng, options, q_ref=q0)[0] for q0 in starts])
    return starts, ends.reshape(n_pairs, 6)


def _random_turns(rng: np.random.Generator, m: int, lo: float, hi: float) -> np.ndarray:
    """``m`` rotations ``(m, 3, 3)`` about uniformly random axes by angles uniform in ``[lo, hi]`` [rad]."""
    return rotvec_to_matrix(_random_unit(rng, m) * rng.uniform(lo, hi, m)[:, None])


def _moved_flange_targets(model: RobotModel, plate: Plate, q0: np.ndarray, turns: np.ndarray,
                          shifts: np.ndarray) -> np.ndarray:
    """Flange targets ``(m, 4, 4)`` that turn the plate (frame of eq. 38-40) of configuration ``q0`` about its
    centre by ``turns`` ``(m, 3, 3)`` (in the base frame) and move its centre by ``shifts`` ``(m, 3)`` [m]."""
    plate2flange = model.tool2flange @ _plate_centre_flange(plate)
    P0 = flange2base(_flange_model(model), q0)[0] @ plate2flange
    P1 = np.broadcast_to(P0, (len(turns), 4, 4)).copy()
    P1[:, :3, :3] = turns @ P0[:3, :3]
    P1[:, :3, 3] += shifts
    return P1 @ invert_transform(plate2flange)


def _local_motions(model, station, plate, n_pairs, rng, opt, tries_per_start: int = 30):
    """Motion pairs whose end turns the plate by ``opt.turn`` and shifts it by ``opt.shift`` from the start."""
    fm = _flange_model(model)
    starts, ends = [], []
    for k in range(n_pairs):
        for _ in range(max(1, opt.max_attempts // tries_per_start)):
            q0 = sample_configurations(model, station, plate, 1, rng, opt)[0]
            turns = _random_turns(rng, tries_per_start, *opt.turn)
            shifts = _random_unit(rng, tries_per_start) * rng.uniform(*opt.shift, tries_per_start)[:, None]
            F1 = _moved_flange_targets(model, plate, q0, turns, shifts)
            q1, ok = _pick_branches(inverse_kinematics_closed_form(fm, F1), rng, opt, q0, model)
            ok &= np.max(np.abs(wrap_angle(q1 - q0)), axis=1) <= opt.max_joint_step
            ok &= plate_in_view(model, q1, station, plate, opt) & _euler_pitch_ok(model, q1, plate, opt)
            if np.any(ok):
                starts.append(q0)
                ends.append(q1[np.argmax(ok)])
                break
        else:
            raise SamplingError(f"no in-view motion pair with the requested turn found for station {station.name!r} "
                                f"(pair {k})")
    return np.array(starts).reshape(-1, 6), np.array(ends).reshape(-1, 6)


def sample_distance_moves(
    model: RobotModel,
    station: Station,
    plate: Plate,
    distances: np.ndarray,
    rng: np.random.Generator,
    options: SamplingOptions | None = None,
    tries_per_start: int = 30,
) -> tuple[np.ndarray, np.ndarray]:
    """Moves of exactly ``distances[k]`` [m] of the plate centre along random directions.

    Returns ``(q_start, q_end)`` ``(len(distances), 6)`` [rad]; on the nominal model the plate centre moves
    by exactly the requested distance; the plate keeps its orientation when ``options.distance_turn`` is
    ``(0, 0)`` (the default; then every plate point moves by that distance) and otherwise turns about its
    centre by an angle uniform in ``distance_turn`` about a random axis. The end is the closed-form branch
    nearest the start, no joint moving more than ``max_joint_step``.
    """
    dist = np.asarray(distances, dtype=float).reshape(-1)
    if not np.all(np.isfinite(dist)) or np.any(dist <= 0):
        raise ValueError(f"distances must be positive [m], got {dist}")
    opt = options or SamplingOptions()
    fm = _flange_model(model)
    starts, ends = [], []
    for k, d in enumerate(dist):
        found = False
        for _ in range(max(1, opt.max_attempts // tries_per_start)):
            q0 = sample_configurations(model, station, plate, 1, rng, opt)[0]
            if opt.distance_turn[1] > 0:
                turns = _random_turns(rng, tries_per_start, *opt.distance_turn)
                F1 = _moved_flange_targets(model, plate, q0, turns, d * _random_unit(rng, tries_per_start))
            else:  # orientation kept (the random stream of configs written before distance_turn existed)
                F0 = flange2base(fm, q0)[0]
                F1 = np.broadcast_to(F0, (tries_per_start, 4, 4)).copy()
                F1[:, :3, 3] += d * _random_unit(rng, tries_per_start)
            q1, ok = _pick_branches(inverse_kinematics_closed_form(fm, F1), rng, opt, q0, model)
            ok &= np.max(np.abs(wrap_angle(q1 - q0)), axis=1) <= opt.max_joint_step
            ok &= plate_in_view(model, q1, station, plate, opt)
            if np.any(ok):
                starts.append(q0)
                ends.append(q1[np.argmax(ok)])
                found = True
                break
        if not found:
            raise SamplingError(f"no in-view move of {d * MM_PER_M:.1f} mm found for station {station.name!r} (move {k})")
    return np.array(starts).reshape(-1, 6), np.array(ends).reshape(-1, 6)
