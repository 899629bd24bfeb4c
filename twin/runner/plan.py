"""A campaign's pose plan: every commanded configuration, in measurement order, with its role.

Built from a :class:`~twin.runner.config.CampaignConfig` and its seed only (same seed, same plan), with the
nominal robot and the nominal station placement (see :mod:`twin.runner.sampling`). Pose ids count up
in measurement order; a motion pair is two consecutive rows sharing a ``pair`` id (``start`` then ``end``);
pairs and moves of a group go round-robin over the group's stations.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..dataset import read_joints_csv
from .config import CampaignConfig, PoseGroup
from .sampling import sample_configurations, sample_distance_moves, sample_motion_pairs

__all__ = ["CampaignPlan", "make_plan", "pose_seed"]


def pose_seed(campaign_seed: int, key: str) -> int:
    """A per-pose seed from the campaign seed and a pose key: the same pose gets the same noise whatever the
    order or the process it is measured in (needed for resume and parallel runs)."""
    h = hashlib.sha256(f"{int(campaign_seed)}/{key}".encode()).digest()
    return int.from_bytes(h[:8], "little") >> 1


@dataclass(frozen=True, eq=False)
class CampaignPlan:
    """Rows in measurement order. ``q`` ``(n, 6)`` [rad] commanded; ``pair`` -1 where a row is not in a pair;
    ``role`` is ``start``/``end``/``single``; ``distance`` [m] is the commanded move of a distance move's
    rows (NaN elsewhere)."""

    pose_id: np.ndarray
    q: np.ndarray
    group: np.ndarray
    set: np.ndarray
    station: np.ndarray
    pair: np.ndarray
    role: np.ndarray
    distance: np.ndarray

    @property
    def n(self) -> int:
        return int(self.pose_id.size)

    def rows(self, group: str | None = None, set: str | None = None) -> np.ndarray:
        """Indices of rows of a group and/or set, in order."""
        m = np.ones(self.n, dtype=bool)
        if group is not None:
            m &= self.group == group
        if set is not None:
            m &= self.set == set
        return np.flatnonzero(m)

    def pairs(self, group: str) -> tuple[np.ndarray, np.ndarray]:
        """Row indices ``(start, end)`` of the motion pairs / moves of ``group``."""
        idx = self.rows(group)
        starts = idx[self.role[idx] == "start"]
        ends = idx[self.role[idx] == "end"]
        if starts.size != ends.size or np.any(self.pair[starts] != self.pair[ends]):
            raise ValueError(f"group {group!r}: start and end rows do not pair up")
        return starts, ends


def _group_rows(cfg: CampaignConfig, g: PoseGroup, k: int, stations: dict) -> list[tuple]:
    model = cfg.nominal_model()
    rng = np.random.default_rng([cfg.seed, 7919, k])
    rows: list[tuple] = []  # (q, station, paired, distance)
    if g.kind == "joints_csv":
        assert g.path is not None
        j = read_joints_csv(g.path)
        st = j.station if j.station is not None else np.full(len(j.pose_id), g.stations[0], dtype=object)
        n = len(j.pose_id)
        if g.pairing == "consecutive" and n % 2:
            raise ValueError(f"{g.path}: pairing = 'consecutive' needs an even number of rows, got {n}")
        for i in range(n):
            if str(st[i]) not in stations:
                raise ValueError(f"{g.path}: row {i + 1}: station {st[i]!r} is not a station of the campaign")
            role = None if g.pairing == "none" else ("start" if i % 2 == 0 else "end")
            if role == "end" and st[i] != st[i - 1]:
                raise ValueError(f"{g.path}: rows {i} and {i + 1} form a pair but are at different stations")
            rows.append((j.q[i], str(st[i]), role, np.nan))
        return rows
    for i in range(g.count):
        name = g.stations[i % len(g.stations)]
        station = stations[name]
        if g.kind == "configurations":
            q = sample_configurations(model, station, cfg.plate, 1, rng, g.sampling)[0]
            rows.append((q, name, None, np.nan))
        elif g.kind == "motion_pairs":
            a, b = sample_motion_pairs(model, station, cfg.plate, 1, rng, g.sampling)
            rows.append((a[0], name, "start", np.nan))
            rows.append((b[0], name, "end", np.nan))
        elif g.kind == "distance_moves":
            d = g.distances[i]
            a, b = sample_distance_moves(model, station, cfg.plate, np.array([d]), rng, g.sampling)
            rows.append((a[0], name, "start", d))
            rows.append((b[0], name, "end", d))
        else:  # pragma: no cover - validated by the config loader
            raise ValueError(f"unknown group kind {g.kind!r}")
    return rows


def make_plan(cfg: CampaignConfig) -> CampaignPlan:
    """The campaign's poses in measurement order (groups in config order)."""
    stations = {s.name: s for s in cfg.stations()}
    pid, q, grp, sets, st, pair, role, dist = [], [], [], [], [], [], [], []
    next_pair = 0
    for k, g in enumerate(cfg.groups):
        for qq, name, r, d in _group_rows(cfg, g, k, stations):
            pid.append(len(pid))
            q.append(qq)
            grp.append(g.name)
            sets.append(g.set)
            st.append(name)
            if r == "start":
                pair.append(next_pair)
                role.append("start")
            elif r == "end":
                pair.append(next_pair)
                role.append("end")
                next_pair += 1
            else:
                pair.append(-1)
                role.append("single")
            dist.append(d)
    return CampaignPlan(
        pose_id=np.array(pid, dtype=np.int64),
        q=np.array(q, dtype=float).reshape(-1, 6),
        group=np.array(grp, dtype=object),
        set=np.array(sets, dtype=object),
        station=np.array(st, dtype=object),
        pair=np.array(pair, dtype=np.int64),
        role=np.array(role, dtype=object),
        distance=np.array(dist, dtype=float),
    )
