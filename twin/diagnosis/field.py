"""Errors of the measurement field: an instrument that reports a point ``p`` (measurement frame, ``z`` along the
line of sight, as for the left camera of a stereo rig or a tracker's head) at ``p + sum_k phi_k G_k(p)``.

The fields ``G_k`` are low-order and physical; with ``u = x / z``, ``v = y / z`` (the direction of the point
seen from the instrument), ``rho^2 = (u^2 + v^2) / rho2_h``, ``w = (z - z_c) / z_h`` (depth) and
``w_r = (|p| - r_c) / r_h`` (range), centred and scaled on the campaign's points, ``l = p / |p|`` the line of
sight:

================  ============================================================================================
``radial``        radial lens distortion left in the measurements: ``(x rho^2, y rho^2, 0)``
``tangential``    decentering (Brown's tangential terms, OpenCV's ``p1``, ``p2``): ``z (2uv, rho^2 + 2v^2, 0) / rho2_h``
                  and ``z (rho^2 + 2u^2, 2uv, 0) / rho2_h`` (``rho^2`` here unscaled, ``u^2 + v^2``)
``depth_scale``   a scale that changes with depth (a stereo baseline or focal length slightly off): ``p w``
``depth2``        a depth error growing with the square of the depth offset: ``(0, 0, z_h w^2)``
``range0/1/2``    a range error along the line of sight, constant (a tracker's zero-point offset), linear or
                  quadratic in the range: ``r_h w_r^k l``
``range_sq``      a range error growing with the square of the range, ``r_h (|p| / r_c)^2 l``, with
``range_x/_y``    ``r_h (x / r_c) l`` and ``r_h (y / r_c) l``: a stereo rig whose convergence (vergence) angle is
                  off by ``dphi`` moves a point along its line of sight by about ``|p - c|^2 dphi / B``, ``c`` the
                  other camera's centre at the baseline ``B`` along ``x`` (or ``y``); ``|p - c|^2 = |p|^2 -
                  2 c . p + B^2`` (the constant is ``range0``). Three parameters, in the span of the range
                  polynomial only when ``x, y`` do not vary, and the shape that extrapolates beyond the
                  campaign's ranges
``view1/2``       a bias that follows the plate's tilt to the line of sight (a sphere partly hidden by the plate's
                  rim, a highlight): with ``n`` the plate normal and ``n_perp = n - (n . l) l``: ``n_perp`` and
                  ``|n_perp| n_perp`` (needs each point's plate normal)
``quad_<c>_<m>``  a general quadratic field: coordinate ``c`` of ``G`` is the monomial ``m`` of ``(u, v, w)``
                  (``uu, vv, ww, uv, uw, vw``), scaled to ``z_h``
================  ============================================================================================

Constant and linear parts (a rigid motion, a uniform scale, a shear) are left to the registration of the
frame, the plate and the measurement scale atoms; what the geometry absorbs is projected out anyway. Nothing
here reads truth: the constants come from the measured points.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..transforms import kabsch
from ..units import M_PER_MM
from .features import Field

__all__ = ["FIELD_NAMES", "POINT_FIELDS", "field_applicable", "field_constants", "field_values", "field_atom_specs",
           "plate_normals", "station_mask"]

_MONOMIALS = ("uu", "vv", "ww", "uv", "uw", "vw")
POINT_FIELDS = ("radial", "tangential1", "tangential2", "depth_scale", "depth2", "range0", "range1", "range2") + tuple(
    f"quad_{c}_{m}" for c in "xyz" for m in _MONOMIALS)  # functions of the point alone
FIELD_NAMES = POINT_FIELDS + ("range_sq", "range_x", "range_y", "view1", "view2")


def field_applicable(points: np.ndarray, max_angle: float = 2.0) -> bool:
    """Whether the measured points ``(..., 3)`` [m] look like a line-of-sight frame: every finite point in front
    (``z > 0``) within ``|x / z|, |y / z| < max_angle``, and at least three of them. Otherwise (a frame with ``z``
    up, say) no field atom is built: their ``u, v`` would mean nothing."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 3 or np.any(P[:, 2] <= 0):
        return False
    return bool(np.all(np.abs(P[:, :2]) < max_angle * P[:, 2:3]))


def field_constants(points: np.ndarray) -> dict[str, float]:
    """Centring and scales of the measured points ``(m, 3)`` [m] (finite rows only): ``z_c``, ``z_h``, ``r_c``,
    ``r_h`` [m] and ``rho2_h`` (the largest ``u^2 + v^2``)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1) & (P[:, 2] > 0)]
    if len(P) < 3:
        raise ValueError("field_constants needs points in front of the instrument (z > 0)")
    z = P[:, 2]
    r = np.linalg.norm(P, axis=1)
    u2 = (P[:, 0] / z) ** 2 + (P[:, 1] / z) ** 2
    return {"z_c": float(np.mean(z)), "z_h": float(max(0.5 * np.ptp(z), M_PER_MM)), "r_c": float(np.mean(r)),
            "r_h": float(max(0.5 * np.ptp(r), M_PER_MM)), "rho2_h": float(max(u2.max(), 1e-6))}


def plate_normals(spheres: np.ndarray, seen: np.ndarray, spheres_tool: np.ndarray, n_tool: np.ndarray) -> np.ndarray:
    """The plate normal ``(n, 3)`` of every row in the measurement frame: the rigid fit of the plate's sphere
    centres ``spheres_tool`` ``(3, 3)`` to the row's measured ``spheres`` ``(n, 3, 3)``, applied to ``n_tool``;
    zero for rows with fewer than three spheres seen."""
    out = np.zeros((len(spheres), 3))
    full = np.all(seen, axis=1)
    if np.any(full):
        R, _ = kabsch(np.broadcast_to(spheres_tool, spheres[full].shape), spheres[full])
        out[full] = R @ np.asarray(n_tool, dtype=float)
    return out


def field_values(features, points: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """``G_k(p)`` ``(m, K, 3)`` [m per unit phi] of the field ``features`` (:class:`twin.diagnosis.features.Field`:
    ``g`` the field's name, with its constants) at the points ``(m, 3)`` [m] in the measurement frame; ``normals``
    ``(m, 3)``: the plate normal at each point, for the view fields (zero normals give zero)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    out = np.zeros((len(P), len(features), 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = x / z, y / z
        r = np.linalg.norm(P, axis=1)
        los = P / r[:, None]
    for k, f in enumerate(features):
        if not isinstance(f, Field):
            raise ValueError(f"not a field feature: {f!r}")
        g, zc, zh, r2h = f.g, f.z_c, f.z_h, f.rho2_h
        w = (z - zc) / zh
        rho2 = (u * u + v * v) / r2h
        if g == "radial":
            out[:, k, 0], out[:, k, 1] = x * rho2, y * rho2
        elif g == "tangential1":
            out[:, k, 0], out[:, k, 1] = z * 2 * u * v / r2h, z * (u * u + v * v + 2 * v * v) / r2h
        elif g == "tangential2":
            out[:, k, 0], out[:, k, 1] = z * (u * u + v * v + 2 * u * u) / r2h, z * 2 * u * v / r2h
        elif g == "depth_scale":
            out[:, k] = P * w[:, None]
        elif g == "depth2":
            out[:, k, 2] = zh * w * w
        elif g in ("range0", "range1", "range2"):
            wr = (r - f.r_c) / f.r_h
            out[:, k] = (f.r_h * wr ** int(g[-1]))[:, None] * los
        elif g == "range_sq":
            out[:, k] = (f.r_h * (r / f.r_c) ** 2)[:, None] * los
        elif g in ("range_x", "range_y"):
            out[:, k] = (f.r_h * P[:, "xy".index(g[-1])] / f.r_c)[:, None] * los
        elif g in ("view1", "view2"):
            if normals is None:
                raise ValueError(f"the field {g!r} needs the plate normal of every point")
            nrm = np.asarray(normals, dtype=float).reshape(-1, 3)
            n_perp = nrm - np.sum(nrm * los, axis=1)[:, None] * los
            scale = zh if g == "view1" else zh * np.linalg.norm(n_perp, axis=1)[:, None]
            out[:, k] = n_perp * scale
        elif g.startswith("quad_"):
            _, c, m = g.split("_")
            s = 1.0 / np.sqrt(r2h)
            var = {"u": u * s, "v": v * s, "w": w}
            out[:, k, "xyz".index(c)] = zh * var[m[0]] * var[m[1]]
        else:
            raise ValueError(f"unknown field {g!r}; known: {FIELD_NAMES}")
    if not np.all(np.isfinite(out)):
        raise ValueError("field features are not finite: points at or behind the instrument (z <= 0)")
    return out


def station_mask(features, station_names: np.ndarray) -> np.ndarray:
    """``(m, K)``: 1 where a field feature applies to the row's station (a feature with ``"station"`` acts on
    that station's rows only: an instrument refocused, or set up anew, at each station), else 0."""
    names = np.asarray(station_names).astype(str)
    return np.stack([np.ones(len(names)) if f.station is None else (names == str(f.station)).astype(float)
                     for f in features], axis=1)


def field_atom_specs(consts: dict, n_tool: np.ndarray | None = None,
                     stations: list[str] | None = None) -> list[tuple[str, tuple[Field, ...], str]]:
    """``(channel, features, words)`` of the field atoms: the physical ones, each small, and the general
    quadratic field (a broad atom). ``n_tool``: the plate normal in the plate frame (for the view fields; none
    without it). ``stations``: with two or more, the small physical fields also once per station (an
    instrument set up anew at each station has its own)."""
    def feats(*names, **extra):
        return tuple(Field(g=n, **consts, **extra) for n in names)

    specs = [
        ("radial distortion", feats("radial"), "radial distortion of the measurement field"),
        ("tangential distortion", feats("tangential1", "tangential2"), "decentering (tangential) distortion of the measurement field"),
        ("scale vs depth", feats("depth_scale"), "measurement scale changing with depth"),
        ("depth error vs depth^2", feats("depth2"), "depth error growing with the square of the depth offset"),
        ("range error vs range", feats("range0", "range1", "range2"), "range error along the line of sight, a polynomial of degree 2 in the range"),
        ("range error vs range^2", feats("range_sq", "range_x", "range_y"), "range error along the line of sight growing with the square of the distance to the other camera (a stereo rig's convergence off)"),
        ("quadratic field", feats(*[n for n in FIELD_NAMES if n.startswith("quad_")]), "quadratic distortion of the measurement field"),
    ]
    if n_tool is not None:
        specs.append(("plate tilt to the line of sight",
                      feats("view1", "view2", n_tool=tuple(float(c) for c in n_tool)),
                      "measurement bias following the plate's tilt to the line of sight"))
    if stations is not None and len(stations) > 1:
        for ch, fs, words in [sp for sp in specs if sp[0] != "quadratic field"]:
            specs.append((f"{ch} per station", tuple(replace(f, station=str(st)) for st in stations for f in fs),
                          f"{words}, one per station"))
    return specs
