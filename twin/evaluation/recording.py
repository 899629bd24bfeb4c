"""The Rerun recording of a campaign (rerun-sdk 0.41). THE ONLY MODULE OF THE PROJECT THAT IMPORTS ``rerun``.

Layout of the recording (entity paths), all 3D in the robot base frame ("world", right-handed, z up, metres):

* ``world`` -- view coordinates, logged once.
* ``world/stations/<s>`` -- the measurement frame of station ``<s>`` (its left camera's OpenCV frame), static;
  ``.../left`` and ``.../right`` -- camera frustums (``Pinhole``), static;
  ``.../measured/spheres`` -- triangulated sphere centres of the pose; ``.../measured/plate`` -- the plate frame
  measured from them (eq. 38-40), as a transform with axes.
* ``world/robot/<model>`` -- link frames of the ``nominal``, ``true`` and each ``calibrated/<method>`` model at
  the pose's commanded joints: ``links`` (a line through the frame origins) and ``axes`` (x/y/z arrows).
* ``images/left``, ``images/right`` -- the camera images (JPEG by default; PNG, lossless and full resolution,
  on request), with ``centres`` (detected sphere centres) and ``outlines`` (detected outlines) as 2D overlays.
* ``residuals/<method>/<name>`` -- per-pose residuals as time series.
* ``log`` -- text log (rejected measurements, warnings).
* ``diagnosis/verdict`` -- when the campaign diagnosed its dataset: the residual, the terms found (the robot's,
  the instrument's) and the error before and after, as a Markdown document.

Everything per pose is on the ``pose`` sequence timeline (the pose index in measurement order). A default
blueprint (3D view, both images, residual plots, log) is stored in the file so it opens in a useful layout.

A diagnosis (``twin diagnose``) has its own recording, :func:`record_diagnosis`: ``diagnosis/residual/...``,
``diagnosis/variables/...``, ``diagnosis/workspace/...`` (the robot, the measured points and the residual vectors in
the measurement frame), ``diagnosis/verdict``, ``diagnosis/log`` (layout in ``docs/diagnosis.md``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..camera import CameraIntrinsics
from ..transforms import matrix_to_quat_wxyz
from ..units import MM_PER_M
from .images import encode_image
from .workspace import COLOUR_STOPS, DiagnosisWorkspace, size_colours, view_eye

__all__ = ["CameraView", "StationView", "CampaignRecording", "encode_image", "default_blueprint"]

_AXIS_COLOURS = np.array([[230, 40, 40], [40, 200, 40], [50, 90, 240]], dtype=np.uint8)
MODEL_COLOURS = {
    "nominal": (160, 160, 160),
    "true": (255, 170, 0),
    "distance": (200, 60, 200),
    "full_pose": (60, 160, 230),
    "separation": (40, 200, 120),
    "separation_paper": (20, 120, 70),
    "default": (240, 60, 60),
}


def _media_type(fmt: str) -> str:
    f = fmt.lower().lstrip(".")
    if f in ("jpg", "jpeg"):
        return "image/jpeg"
    if f == "png":
        return "image/png"
    raise ValueError(f"image format must be 'jpg' or 'png', got {fmt!r}")


@dataclass(frozen=True)
class CameraView:
    """A camera of a station for the recording: name, pose in the station's measurement frame (OpenCV axes)
    and intrinsics."""

    name: str
    cam2meas: np.ndarray
    intrinsics: CameraIntrinsics


@dataclass(frozen=True)
class StationView:
    """A station: its measurement frame in the base frame (``meas2base`` ``(4, 4)``) and its cameras."""

    name: str
    meas2base: np.ndarray
    cameras: tuple[CameraView, ...]


def _transform(T: np.ndarray) -> rr.Transform3D:
    T = np.asarray(T, dtype=float)
    q = matrix_to_quat_wxyz(T[:3, :3])
    return rr.Transform3D(translation=T[:3, 3], quaternion=rr.Quaternion(xyzw=[q[1], q[2], q[3], q[0]]))


def default_blueprint(methods: Sequence[str] = (), diagnosis: bool = False) -> rrb.Blueprint:
    """3D view of the cell on the left, the two images on the right, residuals and the log below (and, with
    ``diagnosis``, the diagnosis' verdict beside the log)."""
    bottom = [rrb.TimeSeriesView(origin="residuals", name="residuals per pose"),
              rrb.TextLogView(origin="log", name="log")]
    if diagnosis:
        bottom.append(rrb.TextDocumentView(origin="diagnosis/verdict", name="diagnosis of the dataset"))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="world", name="cell (robot base frame)"),
                rrb.Vertical(
                    rrb.Spatial2DView(origin="images/left", name="left camera"),
                    rrb.Spatial2DView(origin="images/right", name="right camera"),
                ),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(*bottom, column_shares=[3, 2, 2][: len(bottom)]),
            row_shares=[3, 1],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=False,
    )


class CampaignRecording:
    """Writes one ``.rrd`` file (no viewer needed). Use as a context manager or call :meth:`close`."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        application_id: str = "twin-campaign",
        recording_id: str | None = None,
        methods: Sequence[str] = (),
        lossless: bool = False,
        jpeg_quality: int = 85,
        diagnosis: bool = False,
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.lossless = lossless
        self.jpeg_quality = jpeg_quality
        self._rec = rr.RecordingStream(application_id, recording_id=recording_id or self.path.stem)
        self._rec.save(str(self.path), default_blueprint=default_blueprint(methods, diagnosis))
        self._rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._stations: dict[str, StationView] = {}
        self._closed = False

    # --- static --------------------------------------------------------------------------------
    def log_stations(self, stations: Sequence[StationView]) -> None:
        """Measurement frames and camera frustums, once (static)."""
        for st in stations:
            self._stations[st.name] = st
            base = f"world/stations/{st.name}"
            self._rec.log(base, _transform(st.meas2base), static=True)
            for cam in st.cameras:
                K = cam.intrinsics
                self._rec.log(f"{base}/{cam.name}", _transform(cam.cam2meas), static=True)
                self._rec.log(
                    f"{base}/{cam.name}",
                    rr.Pinhole(
                        image_from_camera=K.K,
                        resolution=[K.width, K.height],
                        camera_xyz=rr.ViewCoordinates.RDF,
                        image_plane_distance=0.15,
                    ),
                    static=True,
                )

    # --- per pose ------------------------------------------------------------------------------
    def set_pose(self, index: int) -> None:
        """Select the ``pose`` timeline position for what follows."""
        if index < 0:
            raise ValueError(f"index must be >= 0, got {index}")
        self._rec.set_time("pose", sequence=int(index))

    def log_images(
        self,
        images: Mapping[str, np.ndarray | bytes],
        *,
        image_format: str | None = None,
        overlays: Mapping[str, Mapping[str, object]] | None = None,
    ) -> None:
        """Camera images (arrays are encoded here; bytes are logged as they are, in ``image_format``) and
        their 2D overlays: ``overlays[camera] = {"centres_px": (k, 2), "outlines_px": [(m, 2), ...]}``."""
        for cam, img in images.items():
            if isinstance(img, (bytes, bytearray)):
                if image_format is None:
                    raise ValueError("image_format is required when images are given as encoded bytes")
                data, media = bytes(img), _media_type(image_format)
            else:
                data, media = encode_image(np.asarray(img), lossless=self.lossless, jpeg_quality=self.jpeg_quality)
            self._rec.log(f"images/{cam}", rr.EncodedImage(contents=data, media_type=media))
        for cam, ov in (overlays or {}).items():
            centres = np.asarray(ov.get("centres_px", np.zeros((0, 2))), dtype=float).reshape(-1, 2)
            self._rec.log(f"images/{cam}/centres", rr.Points2D(centres, radii=4.0, colors=[255, 60, 60]))
            outlines = [np.asarray(o, dtype=float).reshape(-1, 2) for o in ov.get("outlines_px", [])]
            outlines = [np.vstack([o, o[:1]]) for o in outlines if len(o)]
            self._rec.log(f"images/{cam}/outlines", rr.LineStrips2D(outlines, radii=1.5, colors=[60, 220, 60]))

    def log_measurement(self, station: str, spheres_meas: np.ndarray, seen: np.ndarray, plate2meas: np.ndarray | None) -> None:
        """Triangulated centres ``(3, 3)`` [m] (rows where ``seen``) and the measured plate frame, in the
        station's measurement frame; clears the other stations' measurements."""
        if station not in self._stations:
            raise ValueError(f"station {station!r} was not logged with log_stations (known: {sorted(self._stations)})")
        for other in self._stations:
            if other != station:
                self._rec.log(f"world/stations/{other}/measured", rr.Clear(recursive=True))
        base = f"world/stations/{station}/measured"
        pts = np.asarray(spheres_meas, dtype=float)[np.asarray(seen, dtype=bool)]
        self._rec.log(f"{base}/spheres", rr.Points3D(pts, radii=0.0127, colors=[230, 230, 230]))
        if plate2meas is not None:
            self._rec.log(f"{base}/plate", _transform(plate2meas))
            self._rec.log(f"{base}/plate", rr.TransformAxes3D(0.05))
        else:
            self._rec.log(f"{base}/plate", rr.Clear(recursive=False))

    def log_robot(self, frames: Mapping[str, np.ndarray]) -> None:
        """Link frames ``(7, 4, 4)`` (base frame) per model name (``nominal``, ``true``, ``calibrated/<m>``)."""
        for name, F in frames.items():
            F = np.asarray(F, dtype=float)
            if F.ndim != 3 or F.shape[1:] != (4, 4):
                raise ValueError(f"frames[{name!r}] must have shape (k, 4, 4), got {F.shape}")
            colour = MODEL_COLOURS.get(name.split("/")[-1], (200, 200, 200))
            path = f"world/robot/{name}"
            self._rec.log(f"{path}/links", rr.LineStrips3D([F[:, :3, 3]], radii=0.004, colors=[colour]))
            origins = np.repeat(F[:, :3, 3], 3, axis=0)
            vectors = np.concatenate([F[k, :3, :3].T * 0.05 for k in range(F.shape[0])])
            self._rec.log(
                f"{path}/axes", rr.Arrows3D(origins=origins, vectors=vectors, colors=np.tile(_AXIS_COLOURS, (F.shape[0], 1)))
            )

    def log_scalars(self, values: Mapping[str, float]) -> None:
        """Scalars at the current pose, e.g. ``{"residuals/separation/angle_deg": 0.02}``."""
        for path, v in values.items():
            if not np.isfinite(v):
                continue
            self._rec.log(path, rr.Scalars(float(v)))

    def log_text(self, text: str, level: str = "INFO") -> None:
        """A line of the text log (``level`` one of TRACE, DEBUG, INFO, WARN, ERROR, CRITICAL)."""
        self._rec.log("log", rr.TextLog(text, level=getattr(rr.TextLogLevel, level.upper())))

    def log_diagnosis(self, markdown: str) -> None:
        """The diagnosis' verdict on the campaign's dataset (a Markdown document at ``diagnosis/verdict``, static)."""
        self._rec.log("diagnosis/verdict", rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)

    # --- end -----------------------------------------------------------------------------------
    def close(self) -> Path:
        if not self._closed:
            self._rec.flush(timeout_sec=60.0)
            self._rec.disconnect()
            self._closed = True
        return self.path

    def __enter__(self) -> "CampaignRecording":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_recording(path: str | os.PathLike) -> dict[str, list]:
    """Chunks of a recording grouped by entity path: ``{entity_path: [pyarrow.RecordBatch, ...]}`` (tests, tools)."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream():
        out.setdefault(str(chunk.entity_path), []).append(chunk.to_record_batch())
    return out


__all__.append("read_recording")


# ------------------------------------------------------------------------------------------------
# Diagnosis recording
# ------------------------------------------------------------------------------------------------

DIAGNOSIS_ROOT = "diagnosis"
_BEFORE_COLOUR = (220, 50, 50)
_AFTER_COLOUR = (40, 110, 230)
_FLOOR_COLOUR = (90, 90, 90)


def _workspace_views(ws: DiagnosisWorkspace) -> list[rrb.Spatial3DView]:
    """One 3-D view per model (geometric: before; extended: after): the workspace map of that model, the robot at
    the time cursor's row and that row's residual arrows, the scale arrow."""
    root = f"{DIAGNOSIS_ROOT}/workspace"
    position, target, up = view_eye(ws)
    eye = rrb.archetypes.EyeControls3D(position=position, look_target=target, eye_up=up)
    views = []
    for tag, other, what in (("before", "after", "geometric"), ("after", "before", "extended")):
        views.append(rrb.Spatial3DView(
            origin=root, name=f"{what}: arrows x{ws.arrow_scale:g}, red {ws.colour_max_mm:g} mm",
            contents=["+ $origin/**", f"- $origin/map/{other}", f"- $origin/arrows/{other}"], eye_controls=eye))
    return views


def diagnosis_blueprint(channels: Sequence[str] = (), workspace: DiagnosisWorkspace | None = None) -> rrb.Blueprint:
    """Residual per held-out row (geometric only, extended, noise floor) and the verdict on top; the telling
    variables (joints, approach directions, recorded channels) and the text log below. Every plot is drawn
    against the timeline chosen in the time panel: ``pose`` (measurement order) or a variable's own timeline
    (``q1_mdeg`` ... ``q6_mdeg``, ``temp_mdegC``, ``t_s``), which turns the residual plot into a scatter plot
    of the residual against that variable. With a ``workspace``, two 3-D views on the left (the geometric and
    the extended model: the map of every held-out point coloured by its residual, the robot at the current row
    with its residual arrows) and the legend beside the verdict."""
    def plot(origin: str, name: str) -> rrb.TimeSeriesView:
        # the whole timeline on the x axis: on a variable's timeline the rows are sparse (millidegree steps) and
        # the default view range shows only the neighbourhood of the time cursor
        full = rr.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
        return rrb.TimeSeriesView(origin=origin, name=name, axis_x=rrb.archetypes.TimeAxis(view_range=full))

    bottom = [
        plot(f"{DIAGNOSIS_ROOT}/variables/q_deg", "commanded joints [deg]"),
        plot(f"{DIAGNOSIS_ROOT}/variables/approach_sign", "approach direction (-1/+1)"),
    ]
    for ch in channels:
        bottom.append(plot(f"{DIAGNOSIS_ROOT}/variables/{ch}", ch))
    bottom.append(plot(f"{DIAGNOSIS_ROOT}/terms", "terms of the extended model (vs their channel's timeline)"))
    bottom.append(rrb.TextLogView(origin=f"{DIAGNOSIS_ROOT}/log", name="verdict log"))
    residual = plot(f"{DIAGNOSIS_ROOT}/residual", "validation residual RMS per coordinate [mm]")
    verdict = rrb.TextDocumentView(origin=f"{DIAGNOSIS_ROOT}/verdict", name="verdict")
    if workspace is None:
        top = rrb.Horizontal(residual, verdict, column_shares=[3, 1])
    else:
        legend = rrb.TextDocumentView(origin=f"{DIAGNOSIS_ROOT}/workspace/legend", name="legend of the 3-D views")
        top = rrb.Horizontal(*_workspace_views(workspace),
                             rrb.Vertical(residual, rrb.Tabs(verdict, legend, active_tab=0), row_shares=[1, 1]),
                             column_shares=[2, 2, 2])
    return rrb.Blueprint(
        rrb.Vertical(top, rrb.Horizontal(*bottom), row_shares=[3, 2]),
        rrb.TimePanel(state="expanded", timeline="pose"),
        collapse_panels=False,
    )


# Where each candidate effect shows (the variables its regressor is built from), as timelines of the recording.
TELLING_TIMELINES = {
    "compliance": ("q2_mdeg", "q3_mdeg"),  # gravity torque: shoulder and elbow angles
    "backlash": ("pose",),  # approach directions: diagnosis/variables/approach_sign on the pose timeline
    "cyclic": tuple(f"q{j}_mdeg" for j in range(1, 7)),
    "gear_ratio": tuple(f"q{j}_mdeg" for j in range(1, 7)),
    "coupling": ("q5_mdeg",),
    "thermal": ("temp_mdegC", "t_s"),
    "plate_geometry": ("q4_mdeg", "q5_mdeg", "q6_mdeg"),  # the wrist turns the plate in front of the camera
    "tilt": ("pose",),  # the carried moment changes with the whole posture
}


def _verdict_markdown(verdict: Mapping[str, object], timelines: Sequence[str]) -> str:
    eff = list(verdict.get("effects") or [])
    floor = (verdict.get("noise_floor") or {}).get("position_mm")
    p = verdict.get("p_value")
    p_txt = f"{p:.3g}" if isinstance(p, (int, float)) else str(p)
    floor_txt = f"{floor:.5f}" if isinstance(floor, (int, float)) else str(floor)
    lines = [
        "# Diagnosis",
        "",
        f"* structured: **{verdict.get('structured')}** (p = {p_txt}, alpha = {verdict.get('alpha')})",
        f"* effects: **{', '.join(eff) if eff else 'none'}** (explained: {verdict.get('explained')})",
        f"* noise floor: {floor_txt} mm per coordinate",
    ]
    for tag in ("before", "after"):
        pos = (verdict.get(tag) or {}).get("position_mm")
        if pos:
            lines.append(f"* validation position error {tag}: mean {pos['mean']:.5f}, rms {pos['rms']:.5f}, "
                         f"max {pos['max']:.5f} mm")
    for e in eff:
        tl = [t for t in TELLING_TIMELINES.get(str(e), ()) if t in timelines]
        if tl:
            lines.append(f"* `{e}` shows against the timeline " + ", ".join(f"`{t}`" for t in tl))
    atoms = list(verdict.get("atoms") or [])
    if atoms:
        frac = verdict.get("explained_fraction")
        lines += ["", "## Terms of the extended model" + (f" ({100 * frac:.0f} % of the held-out excess explained)"
                                                           if isinstance(frac, (int, float)) else ""), ""]
        for k, a in enumerate(atoms):
            lines.append(f"* term{k + 1}: {a.get('text')} (channel `{a.get('channel')}`)"
                         + (" *minor*" if a.get("minor") else ""))
    for d in verdict.get("alternatives") or []:
        lines.append(f"* the data cannot tell `{d.get('of')}` from `{d.get('alternative')}`")
    lines += ["", "Switch the time panel to a variable's timeline to plot the residual against it:",
              ", ".join(f"`{t}`" for t in timelines) + "."]
    notes = list(verdict.get("notes") or [])
    if notes:
        lines += ["", "## Notes", ""] + [f"* {n}" for n in notes]
    return "\n".join(lines) + "\n"


def record_diagnosis(
    path: str | os.PathLike,
    series: Mapping[str, np.ndarray],
    verdict: Mapping[str, object],
    *,
    workspace: DiagnosisWorkspace | None = None,
    application_id: str = "twin-diagnosis",
) -> Path:
    """Write a diagnosis as an ``.rrd`` recording (no viewer needed); returns ``path``.

    ``series``: :attr:`twin.diagnosis.DiagnosisResult.series` (per held-out row: ``dataset_row``,
    ``residual_rms_mm_before``/``_after`` [mm, RMS per sphere coordinate], ``q_deg`` ``(n, N)`` (deg; mm for a
    prismatic joint), ``approach_sign`` ``(n, N)``, optional ``temp_c``/``t_s``, optional ``terms``: per term of the extended
    model ``{label: {value (n,), unit, channel}}``); ``verdict``: the content of ``diagnosis.json``
    (:func:`twin.diagnosis.diagnosis_dict`; ``structured``, ``p_value``, ``effects``, ``noise_floor``, ...).

    Entities (layout in ``docs/diagnosis.md``): ``diagnosis/residual/{before,after,noise_floor}``,
    ``diagnosis/variables/q_deg/q1..qN``, ``diagnosis/variables/approach_sign/j1..jN``,
    ``diagnosis/variables/{temp_c,t_s}`` (when recorded), ``diagnosis/terms/term<k>`` (each term of the
    extended model), ``diagnosis/verdict`` (markdown) and
    ``diagnosis/log`` (text log). Every row is on the ``pose`` timeline (its row in the dataset, measurement
    order) and on one timeline per variable (``q<j>_mdeg`` [millidegree; micrometre for a prismatic joint],
    ``temp_mdegC`` [milli deg C],
    ``t_s`` [s, duration]) so that the residual plots against any of them.

    ``workspace`` (:func:`twin.evaluation.workspace.diagnosis_workspace`, the same held-out rows): the robot and
    the residuals in the measurement frame [m] under ``diagnosis/workspace``: ``robot`` (the calibrated skeleton,
    a line strip through its frame origins, base to flange) and ``robot/joints`` (the origins), ``measured`` (the
    row's measured points), ``arrows/before`` and ``arrows/after`` (the residual vectors, measured minus
    predicted, of the geometric and the extended model at the measured points, times ``arrow_scale``, coloured by
    size) and ``robot/tool`` (a thin line from the flange to each measured point), on the drawn rows and the same
    timelines; static: ``map/before`` and ``map/after`` (every held-out
    row's points coloured by their residual's size), ``base`` (the robot base's axes), ``scale`` (an arrow of
    ``colour_max_mm`` at the arrow scale, labelled) and ``legend`` (markdown: colour map, scale, frame, rows).
    """
    for key in ("dataset_row", "residual_rms_mm_before", "residual_rms_mm_after", "q_deg"):
        if key not in series:
            raise ValueError(f"series lacks {key!r} (has {sorted(series)}): pass DiagnosisResult.series")
    rows = np.asarray(series["dataset_row"], dtype=np.int64)
    n = rows.size
    if n == 0:
        raise ValueError("series['dataset_row'] is empty: a diagnosis recording needs held-out rows")
    before = np.asarray(series["residual_rms_mm_before"], dtype=float)
    after = np.asarray(series["residual_rms_mm_after"], dtype=float)
    q_deg = np.asarray(series["q_deg"], dtype=float)
    nj = q_deg.shape[1] if q_deg.ndim == 2 else 0
    if before.shape != (n,) or after.shape != (n,) or q_deg.shape != (n, nj) or nj < 1:
        raise ValueError(f"series shapes disagree: dataset_row {rows.shape}, before {before.shape}, "
                         f"after {after.shape}, q_deg {q_deg.shape} (expected (n,), (n,), (n,), (n, N))")
    extra = {k: np.asarray(series[k], dtype=float) for k in ("temp_c", "t_s") if series.get(k) is not None}
    sign = None if series.get("approach_sign") is None else np.asarray(series["approach_sign"], dtype=float)
    for key, a, shape in [("residual_rms_mm_before", before, (n,)), ("residual_rms_mm_after", after, (n,)),
                          ("q_deg", q_deg, (n, nj))] + [(k, a, (n,)) for k, a in extra.items()] + (
                          [] if sign is None else [("approach_sign", sign, (n, nj))]):
        if a.shape != shape:
            raise ValueError(f"series[{key!r}] must have shape {shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"series[{key!r}] holds non-finite values (row {int(np.flatnonzero(~np.isfinite(a).reshape(n, -1).all(axis=1))[0])})")
    terms = dict(series.get("terms") or {})
    for label, term in terms.items():
        v = np.asarray(term.get("value"), dtype=float) if isinstance(term, Mapping) else None
        if v is None or v.shape != (n,) or not np.all(np.isfinite(v)):
            raise ValueError(f"series['terms'][{label!r}]['value'] must be {n} finite numbers")
        term["value"] = v
    nf = verdict.get("noise_floor")
    floor = nf.get("position_mm") if isinstance(nf, Mapping) else None
    if not isinstance(floor, (int, float, np.floating)) or not np.isfinite(floor) or floor <= 0:
        raise ValueError(f"verdict['noise_floor']['position_mm'] must be a positive number, got {floor!r}")
    for key in ("structured", "p_value", "effects"):
        if key not in verdict:
            raise ValueError(f"verdict lacks {key!r}: pass the content of diagnosis.json")

    if workspace is not None and not np.array_equal(np.asarray(workspace.rows), rows):
        raise ValueError("workspace.rows must be series['dataset_row'] (the workspace of the same diagnosis)")
    channels = [k for k in ("temp_c", "t_s") if k in extra]
    timelines = ["pose"] + [f"q{j + 1}_mdeg" for j in range(nj)] + (["temp_mdegC"] if "temp_c" in extra else []) + (
        ["t_s"] if "t_s" in extra else [])

    def index_columns(sel=slice(None)) -> list:
        """One time column per timeline for the rows ``sel``, shared by every per-row entity."""
        cols = [rr.TimeColumn("pose", sequence=rows[sel])]
        for j in range(nj):
            cols.append(rr.TimeColumn(f"q{j + 1}_mdeg", sequence=np.round(q_deg[sel, j] * 1e3).astype(np.int64)))
        if "temp_c" in extra:
            cols.append(rr.TimeColumn("temp_mdegC", sequence=np.round(extra["temp_c"][sel] * 1e3).astype(np.int64)))
        if "t_s" in extra:
            cols.append(rr.TimeColumn("t_s", duration=extra["t_s"][sel]))
        return cols

    indexes = index_columns()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(application_id, recording_id=f"{path.parent.name}/{path.stem}")
    rec.save(str(path), default_blueprint=diagnosis_blueprint(channels, workspace))
    root = DIAGNOSIS_ROOT
    try:
        # series styles (static): residuals as markers so that they read as a scatter plot on a variable's
        # timeline; the floor as a line
        rec.log(f"{root}/residual/before", rr.SeriesPoints(colors=[_BEFORE_COLOUR], names=["geometric only"],
                                                           marker_sizes=[3.0]), static=True)
        rec.log(f"{root}/residual/after", rr.SeriesPoints(colors=[_AFTER_COLOUR], names=["extended"],
                                                          marker_sizes=[3.0]), static=True)
        rec.log(f"{root}/residual/noise_floor", rr.SeriesLines(colors=[_FLOOR_COLOUR], names=["noise floor"]),
                static=True)
        rec.send_columns(f"{root}/residual/before", indexes, rr.Scalars.columns(scalars=before))
        rec.send_columns(f"{root}/residual/after", indexes, rr.Scalars.columns(scalars=after))
        rec.send_columns(f"{root}/residual/noise_floor", indexes, rr.Scalars.columns(scalars=np.full(n, float(floor))))
        for j in range(nj):
            rec.send_columns(f"{root}/variables/q_deg/q{j + 1}", indexes, rr.Scalars.columns(scalars=q_deg[:, j]))
        if sign is not None:
            for j in range(nj):
                rec.log(f"{root}/variables/approach_sign/j{j + 1}", rr.SeriesPoints(marker_sizes=[2.0]), static=True)
                rec.send_columns(f"{root}/variables/approach_sign/j{j + 1}", indexes,
                                 rr.Scalars.columns(scalars=sign[:, j]))
        for ch in channels:
            rec.send_columns(f"{root}/variables/{ch}", indexes, rr.Scalars.columns(scalars=extra[ch]))
        # every term of the extended model on the held-out rows: switch the time panel to its channel's
        # timeline (q<j>_mdeg, t_s, temp_mdegC) to see the term against what it depends on
        for k, (label, term) in enumerate(terms.items()):
            ent = f"{root}/terms/term{k + 1}"
            rec.log(ent, rr.SeriesPoints(names=[f"{label} [{term['unit']}] vs {term['channel']}"], marker_sizes=[2.5]),
                    static=True)
            rec.send_columns(ent, indexes, rr.Scalars.columns(scalars=term["value"]))
        rec.log(f"{root}/verdict", rr.TextDocument(_verdict_markdown(verdict, timelines),
                                                   media_type=rr.MediaType.MARKDOWN), static=True)
        if workspace is not None:
            _log_workspace(rec, workspace, index_columns(workspace.drawn))
        # the verdict log at the first held-out row (on every timeline), so that it shows from the start
        eff = list(verdict.get("effects") or [])
        level = rr.TextLogLevel.WARN if verdict.get("structured") else rr.TextLogLevel.INFO
        texts = [
            (f"structured={verdict.get('structured')} p_value={verdict.get('p_value')} "
             f"effects={','.join(eff) if eff else 'none'}", level),
            (f"noise floor {floor} mm per coordinate", rr.TextLogLevel.INFO),
        ] + [(str(note), rr.TextLogLevel.INFO) for note in verdict.get("notes") or []]
        rec.set_time("pose", sequence=int(rows.min()))
        for j in range(nj):
            rec.set_time(f"q{j + 1}_mdeg", sequence=int(np.round(q_deg[:, j].min() * 1e3)))
        if "temp_c" in channels:
            rec.set_time("temp_mdegC", sequence=int(np.round(np.min(extra["temp_c"]) * 1e3)))
        if "t_s" in channels:
            rec.set_time("t_s", duration=float(np.min(extra["t_s"])))
        for text, lvl in texts:
            rec.log(f"{root}/log", rr.TextLog(text, level=lvl))
    finally:
        rec.flush(timeout_sec=60.0)
        rec.disconnect()
    return path


SKELETON_COLOUR = (125, 100, 80)
_MEASURED_POINT_COLOUR = (30, 30, 30)


def _view_coordinates(up: np.ndarray):
    """The view coordinates whose up axis is the frame's axis nearest to ``up``."""
    k = int(np.argmax(np.abs(up)))
    name = f"RIGHT_HAND_{'XYZ'[k]}_{'UP' if up[k] > 0 else 'DOWN'}"
    return getattr(rr.ViewCoordinates, name)


def _workspace_legend(ws: DiagnosisWorkspace) -> str:
    stops = ", ".join(f"{name} {share * ws.colour_max_mm:g} mm" for share, name, _ in COLOUR_STOPS)
    lines = [
        "# The 3-D views",
        "",
        f"* frame: the measurement frame of station `{ws.station}` [m]",
        "* left: the geometric model (before); right: the extended model (after)",
        f"* colour of a point or an arrow: the length [mm] of its residual (measured minus predicted): {stops} and "
        "beyond; grey: not seen",
        f"* **arrows x{ws.arrow_scale:g}**: each residual vector is drawn {ws.arrow_scale:g} times its length, from "
        f"the measured point; the labelled arrow `scale` is {ws.colour_max_mm:g} mm at that scale",
        f"* the map (small points, static): every measured point of the {ws.rows.size} held-out rows",
        "* the robot (a bronze skeleton: base, joint frames, flange; thin lines to the measured points), the row's "
        f"measured points (black) and arrows: the row at the time cursor ({ws.drawn.size} of {ws.rows.size} rows "
        "drawn)",
    ]
    lines += [f"* {n}" for n in ws.notes]
    return "\n".join(lines) + "\n"


def _log_workspace(rec: rr.RecordingStream, ws: DiagnosisWorkspace, indexes: list) -> None:
    """The workspace entities (:func:`record_diagnosis`): static map, base, scale and legend; per drawn row the
    robot, the measured points and the residual arrows on ``indexes`` (the drawn rows' time columns)."""
    root = f"{DIAGNOSIS_ROOT}/workspace"
    rec.log(root, _view_coordinates(ws.up), static=True)
    seen = np.all(np.isfinite(ws.measured_m), axis=2)
    for tag in ("before", "after"):
        rec.log(f"{root}/map/{tag}", rr.Points3D(ws.measured_m[seen], radii=-1.5,
                                                 colors=size_colours(ws.size_mm[tag][seen], ws.colour_max_mm)),
                static=True)
    axis_len = 0.1 * ws.extent_m
    rec.log(f"{root}/base", rr.Arrows3D(origins=np.repeat(ws.base2frame[None, :3, 3], 3, axis=0),
                                        vectors=ws.base2frame[:3, :3].T * axis_len, colors=_AXIS_COLOURS,
                                        labels=["base x", "base y", "base z"], show_labels=False), static=True)
    # the scale arrow: colour_max_mm at the arrow scale along the base's x, under the middle of the points (the middle
    # of their box in the base frame, at its bottom)
    R, t = ws.base2frame[:3, :3], ws.base2frame[:3, 3]
    pts_base = (ws.measured_m[seen] - t) @ R
    lo, hi = pts_base.min(axis=0), pts_base.max(axis=0)
    under = R @ np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]]) + t
    rec.log(f"{root}/scale", rr.Arrows3D(
        origins=[under], vectors=[R[:, 0] * ws.colour_max_mm / MM_PER_M * ws.arrow_scale],
        colors=[COLOUR_STOPS[-1][2]], labels=[f"{ws.colour_max_mm:g} mm, red (arrows x{ws.arrow_scale:g})"],
        show_labels=True), static=True)
    rec.log(f"{root}/legend", rr.TextDocument(_workspace_legend(ws), media_type=rr.MediaType.MARKDOWN), static=True)

    d = ws.drawn
    skel = ws.skeleton_m
    rec.send_columns(f"{root}/robot", indexes,
                     rr.LineStrips3D.columns(strips=list(skel), colors=np.tile(SKELETON_COLOUR, (d.size, 1)),
                                             radii=np.full(d.size, -2.5)))
    n_f = skel.shape[1]
    rec.send_columns(f"{root}/robot/joints", indexes,
                     rr.Points3D.columns(positions=skel.reshape(-1, 3), colors=np.tile(SKELETON_COLOUR, (d.size * n_f, 1)),
                                         radii=np.full(d.size * n_f, -4.0)).partition(np.full(d.size, n_f)))
    s = seen[d]
    counts = s.sum(axis=1)
    pts = ws.measured_m[d][s]
    flange = np.repeat(skel[:, -1], counts, axis=0)
    rec.send_columns(f"{root}/robot/tool", indexes,
                     rr.LineStrips3D.columns(strips=list(np.stack([flange, pts], axis=1)),
                                             colors=np.tile(SKELETON_COLOUR, (pts.shape[0], 1)),
                                             radii=np.full(pts.shape[0], -1.0)).partition(counts))
    rec.send_columns(f"{root}/measured", indexes,
                     rr.Points3D.columns(positions=pts, colors=np.tile(_MEASURED_POINT_COLOUR, (pts.shape[0], 1)),
                                         radii=np.full(pts.shape[0], -3.0)).partition(counts))
    for tag in ("before", "after"):
        vec = ws.residual_m[tag][d][s] * ws.arrow_scale
        rec.send_columns(f"{root}/arrows/{tag}", indexes,
                         rr.Arrows3D.columns(origins=pts, vectors=vec,
                                             colors=size_colours(ws.size_mm[tag][d][s], ws.colour_max_mm),
                                             radii=np.full(pts.shape[0], -3.0)).partition(counts))


__all__ += ["record_diagnosis", "diagnosis_blueprint", "TELLING_TIMELINES", "SKELETON_COLOUR"]


# ------------------------------------------------------------------------------------------------
# A measured campaign: robot, measured and predicted points, residual per posture
# ------------------------------------------------------------------------------------------------

CAMPAIGN_ROOT = "campaign"
_MEASURED_COLOUR = (30, 30, 30)


def record_measured_campaign(
    path: str | os.PathLike,
    *,
    joint_origins_m: np.ndarray,
    measured_m: np.ndarray,
    predicted_m: Mapping[str, np.ndarray],
    posture_ids: np.ndarray,
    groups: Sequence[str],
    summary_markdown: str = "",
    application_id: str = "twin-measured-campaign",
) -> Path:
    """Write a measured campaign as an ``.rrd`` recording (no viewer needed); returns ``path``.

    Per posture ``k`` (``n`` in all), on the ``posture`` sequence timeline (``posture_ids`` ``(n,)``, e.g. the
    dataset's pose ids), in the measurement frame [m]:

    * ``campaign/robot``: the robot as line segments between its joint frames' origins, ``joint_origins_m``
      ``(n, F, 3)`` (base, every joint, flange: the chain of the URDF);
    * ``campaign/points/measured``: the measured points ``measured_m`` ``(n, K, 3)`` (black; NaN where not seen);
    * ``campaign/points/<model>``: the points each model predicts, ``predicted_m[model]`` ``(n, K, 3)`` (e.g.
      ``geometric`` and ``extended``: before and after), with ``campaign/error/<model>`` the segments from each
      predicted point to its measured one;
    * ``campaign/residual/<model>``: the RMS of the 3-D point error of the posture [mm], a time series;
    * ``campaign/group``: the posture's group (``groups[k]``: training, replayed, new in range, outside), text;
    * ``campaign/summary``: ``summary_markdown`` (static).

    ``ValueError`` naming the argument when shapes disagree or values are not finite (the robot, the measured
    points where seen, the predictions)."""
    J = np.asarray(joint_origins_m, dtype=float)
    M = np.asarray(measured_m, dtype=float)
    ids = np.asarray(posture_ids)
    if J.ndim != 3 or J.shape[2] != 3 or J.shape[1] < 2:
        raise ValueError(f"joint_origins_m must have shape (n, F >= 2, 3), got {J.shape}")
    n = J.shape[0]
    if M.ndim != 3 or M.shape[0] != n or M.shape[2] != 3:
        raise ValueError(f"measured_m must have shape ({n}, K, 3), got {M.shape}")
    if ids.shape != (n,):
        raise ValueError(f"posture_ids must have shape ({n},), got {ids.shape}")
    if len(groups) != n:
        raise ValueError(f"groups must have {n} entries, got {len(groups)}")
    if not np.all(np.isfinite(J)):
        raise ValueError("joint_origins_m holds non-finite values")
    if not predicted_m:
        raise ValueError("predicted_m must name at least one model's predicted points")
    seen = np.all(np.isfinite(M), axis=2)  # (n, K)
    preds = {}
    for name, P in predicted_m.items():
        P = np.asarray(P, dtype=float)
        if P.shape != M.shape or not np.all(np.isfinite(P)):
            raise ValueError(f"predicted_m[{name!r}] must be finite with shape {M.shape}, got {P.shape}")
        preds[str(name)] = P
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(application_id, recording_id=f"{path.parent.name}/{path.stem}")
    names = list(preds)
    blueprint = rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=CAMPAIGN_ROOT, name="robot, measured and predicted points"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin=f"{CAMPAIGN_ROOT}/residual", name="point error per posture [mm]"),
                rrb.TextDocumentView(origin=f"{CAMPAIGN_ROOT}/summary", name="summary"),
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="expanded", timeline="posture"),
        collapse_panels=False,
    )
    rec.save(str(path), default_blueprint=blueprint)
    root = CAMPAIGN_ROOT
    colours = [_BEFORE_COLOUR, _AFTER_COLOUR] + [tuple(int(c) for c in v) for v in MODEL_COLOURS.values()]
    try:
        rec.log(root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if summary_markdown:
            rec.log(f"{root}/summary", rr.TextDocument(summary_markdown, media_type=rr.MediaType.MARKDOWN), static=True)
        for m, name in enumerate(names):
            rec.log(f"{root}/residual/{name}", rr.SeriesLines(colors=[colours[m % len(colours)]], names=[name]),
                    static=True)
        for k in range(n):
            rec.set_time("posture", sequence=int(ids[k]))
            rec.log(f"{root}/robot", rr.LineStrips3D([J[k]], colors=[(120, 120, 120)], radii=[0.004]))
            rec.log(f"{root}/robot/joints", rr.Points3D(J[k], colors=[(90, 90, 90)], radii=[0.008]))
            mk = M[k][seen[k]]
            rec.log(f"{root}/points/measured", rr.Points3D(mk, colors=[_MEASURED_COLOUR], radii=[0.004]))
            rec.log(f"{root}/group", rr.TextLog(str(groups[k])))
            for m, name in enumerate(names):
                P = preds[name][k][seen[k]]
                col = colours[m % len(colours)]
                rec.log(f"{root}/points/{name}", rr.Points3D(P, colors=[col], radii=[0.003]))
                rec.log(f"{root}/error/{name}", rr.LineStrips3D(np.stack([P, mk], axis=1), colors=[col], radii=[0.001]))
                e = np.linalg.norm(P - mk, axis=1)
                rec.log(f"{root}/residual/{name}", rr.Scalars(float(np.sqrt(np.mean(e**2))) * MM_PER_M if e.size else 0.0))
    finally:
        rec.flush(timeout_sec=60.0)
        rec.disconnect()
    return path


__all__ += ["record_measured_campaign"]
