"""Image folders in, datasets out: the instrument's file edges.

The image folder layout (``docs/formats.md``, "Image folder") is what the world writes and what a real
camera rig produces::

    IMAGES/rig.toml  joints.csv  board/<k>_left.png  board/<k>_right.png  pairs/<pose_id>_left.png ...

Nothing here depends on the images having been rendered. The in-memory entry point
:func:`measure_to_dataset` (joints + an iterable of image pairs) measures pairs given as arrays;
:func:`measure_folder` wraps it for a folder. :class:`MeasuredRowsWriter` is the one writer of measured rows
(``poses.csv``) and of their summary: the folder measurement and the runner (``twin campaign``,
``twin measure --render``) both write through it, and :func:`instrument_provenance` is the instrument's part of
a measured dataset's provenance.
"""

from __future__ import annotations

import collections
import csv
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import cv2
import numpy as np

from ..dataset import (
    DatasetError,
    DatasetWriter,
    Joints,
    Plate,
    PoseRow,
    read_dataset,
    read_joints_csv,
    write_dataset_toml,
)
from ..files import open_text, read_toml
from ..units import MM_PER_M
from .calibration import BoardSpec, StereoCalibration, calibrate_stereo
from .measure import MeasureConfig, PairMeasurement, format_status, measure_pair, status_reasons

__all__ = [
    "RigSpec",
    "MeasureSummary",
    "MeasuredRowsWriter",
    "instrument_provenance",
    "read_rig_toml",
    "read_image",
    "board_view_files",
    "pair_files",
    "calibrate_folder",
    "measure_to_dataset",
    "measure_folder",
    "CALIBRATION_FILE",
    "read_plate_toml",
]

RIG_SCHEMA_VERSION = 1
CALIBRATION_FILE = "stereo_calibration.json"
_NAME = re.compile(r"^(\d+)_(left|right)\.png$", re.IGNORECASE)


@dataclass(frozen=True)
class RigSpec:
    """``rig.toml``: image size [px] and the calibration board (no intrinsics: those are estimated)."""

    image_width: int
    image_height: int
    board: BoardSpec
    raw: dict = field(default_factory=dict, compare=False)


def read_rig_toml(path: str | os.PathLike) -> RigSpec:
    """Read and validate ``rig.toml``; errors name the file and the field."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: missing (an image folder holds rig.toml, joints.csv, board/ and pairs/)")
    d = read_toml(p)
    if d.get("schema_version") != RIG_SCHEMA_VERSION:
        raise ValueError(f"{p}: unknown schema_version {d.get('schema_version')!r} (this reader knows {RIG_SCHEMA_VERSION})")
    for k in ("image_width", "image_height"):
        if not isinstance(d.get(k), int) or d[k] <= 0:
            raise ValueError(f"{p}: field {k!r} must be a positive integer [px], got {d.get(k)!r}")
    if not isinstance(d.get("board"), dict):
        raise ValueError(f"{p}: missing table [board]")
    try:
        board = BoardSpec.from_table(d["board"])
    except ValueError as exc:
        raise ValueError(f"{p}: [board]: {exc}") from None
    return RigSpec(d["image_width"], d["image_height"], board, d)


def read_plate_toml(path: str | os.PathLike) -> Plate:
    """The ``[plate]`` table (``sphere_diameter_mm``, ``spheres_mm``) of a TOML file, e.g. a ``dataset.toml``."""
    p = Path(path)
    d = read_toml(p, missing="no such plate file")
    t = d.get("plate")
    if not isinstance(t, dict):
        raise ValueError(f"{p}: missing table [plate] (sphere_diameter_mm, spheres_mm)")
    try:
        dia = float(t["sphere_diameter_mm"]) / MM_PER_M
        s = np.asarray(t["spheres_mm"], dtype=float) / MM_PER_M
    except KeyError as exc:
        raise ValueError(f"{p}: [plate] lacks field {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise ValueError(f"{p}: [plate] fields must be numbers (spheres_mm: three [x, y, z] in mm)") from None
    try:
        return Plate(dia, s)
    except ValueError as exc:
        raise ValueError(f"{p}: [plate]: {exc}") from None


def read_image(path: str | os.PathLike) -> np.ndarray | None:
    """An 8-bit greyscale image ``(h, w)`` (RGB converted), or None when missing or unreadable."""
    p = Path(path)
    if not p.is_file():
        return None
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    return img


def _index(folder: Path) -> dict[int, dict[str, Path]]:
    out: dict[int, dict[str, Path]] = collections.defaultdict(dict)
    if folder.is_dir():
        for f in sorted(folder.iterdir()):
            m = _NAME.match(f.name)
            if m:
                out[int(m.group(1))][m.group(2).lower()] = f
    return dict(out)


def board_view_files(images_dir: str | os.PathLike) -> list[tuple[str, Path | None, Path | None]]:
    """``[(k, left, right), ...]`` of ``board/<k>_left.png`` / ``_right.png`` in order (None if a side is missing)."""
    idx = _index(Path(images_dir) / "board")
    return [(f"{k:03d}", v.get("left"), v.get("right")) for k, v in sorted(idx.items())]


def pair_files(images_dir: str | os.PathLike) -> dict[int, dict[str, Path]]:
    """``{pose_id: {"left": path, "right": path}}`` of ``pairs/<pose_id>_left.png`` / ``_right.png``."""
    return _index(Path(images_dir) / "pairs")


def calibrate_folder(images_dir: str | os.PathLike, **kwargs) -> StereoCalibration:
    """Stereo calibration from ``IMAGES/board/`` with the board of ``IMAGES/rig.toml``.

    Views missing one side or with an unreadable image are passed on as blank images, so that they are
    rejected and reported like any other unusable view. ``kwargs`` go to :func:`calibrate_stereo`.
    """
    images_dir = Path(images_dir)
    rig = read_rig_toml(images_dir / "rig.toml")
    files = board_view_files(images_dir)
    if not files:
        raise ValueError(f"{images_dir / 'board'}: no board views (<k>_left.png / <k>_right.png)")
    blank = np.zeros((rig.image_height, rig.image_width), np.uint8)
    pairs, names = [], []
    for k, fl, fr in files:
        il = read_image(fl) if fl else None
        ir = read_image(fr) if fr else None
        for side, im, f in (("left", il, fl), ("right", ir, fr)):
            if im is not None and im.shape != (rig.image_height, rig.image_width):
                raise ValueError(f"{f}: image is {im.shape[1]}x{im.shape[0]}, rig.toml says {rig.image_width}x{rig.image_height}")
        pairs.append((blank if il is None else il, blank if ir is None else ir))
        names.append(k)
    return calibrate_stereo(pairs, rig.board, names=names, **kwargs)


@dataclass(frozen=True, eq=False)
class MeasureSummary:
    """What a measurement run produced: counts, reasons, timing, and where it went."""

    dataset: Path
    n_rows: int
    n_complete: int
    n_spheres: int
    reasons: dict[str, int]
    time_per_pair_s: tuple[float, ...]
    calibration: StereoCalibration
    validation_error: str = ""

    def to_dict(self) -> dict[str, Any]:
        t = np.asarray(self.time_per_pair_s) if self.time_per_pair_s else np.zeros(1)
        return {
            "dataset": str(self.dataset),
            "rows": self.n_rows,
            "complete_rows": self.n_complete,
            "spheres_measured": self.n_spheres,
            "reasons": self.reasons,
            "time_per_pair_ms": {"median": float(np.median(t) * 1e3), "max": float(t.max() * 1e3)},
            "stereo_rms_px": self.calibration.rms_px,
            "validation_error": self.validation_error,
        }


def instrument_provenance(calib: StereoCalibration, bias_correction: bool) -> str:
    """The instrument's part of a measured dataset's ``provenance``: the stereo calibration it used and how the
    sphere centres were measured."""
    return (
        f"instrument: stereo calibration from {calib.n_views_used} board views (RMS {calib.rms_px:.3f} px, "
        f"baseline {calib.baseline * MM_PER_M:.2f} mm); sphere centres from sub-pixel outlines, "
        f"{'cone (perspective-bias) corrected' if bias_correction else 'ellipse centres (no perspective-bias correction)'}"
    )


class MeasuredRowsWriter:
    """The one writer of measured rows: ``poses.csv`` of a dataset folder, streamed one row at a time (a run that
    stops loses nothing already measured), and the tally a :class:`MeasureSummary` reports.

    ``columns``: the optional columns besides ``status`` (``set``, ``station``, ``pair``, ``temp_c``, ``t_s``);
    :meth:`write` takes a value for each. The caller writes ``dataset.toml``. Use as a context manager, then
    :meth:`summary`.
    """

    COLUMNS = ("set", "station", "pair", "temp_c", "t_s")

    def __init__(self, folder: str | os.PathLike, columns: Sequence[str] = ()) -> None:
        unknown = set(columns) - set(self.COLUMNS)
        if unknown:
            raise ValueError(f"columns: unknown {sorted(unknown)}; known: {list(self.COLUMNS)}")
        self.folder = Path(folder)
        self.columns = tuple(c for c in self.COLUMNS if c in set(columns))
        self._w = DatasetWriter(self.folder, spheres=True, optional=["status", *self.columns])
        self.n_rows = self.n_complete = self.n_spheres = 0
        self.reasons: collections.Counter = collections.Counter()
        self.times: list[float] = []

    def write(self, pose_id: int, q: np.ndarray, spheres: Sequence[np.ndarray | None], status: str, *,
              time_s: float | None = None, **values: Any) -> PoseRow:
        """One row: commanded joints ``q`` ``(6,)`` [rad], the sphere centres (each ``(3,)`` [m] or None), the
        ``status`` cell (:func:`format_status`), a value for each of :attr:`columns` (``pair`` < 0: none), and
        the measurement's wall time ``time_s`` [s] when it counts in the summary."""
        if set(values) != set(self.columns):
            raise ValueError(f"pose_id {pose_id}: values for {sorted(values)}, the writer's columns are "
                             f"{list(self.columns)}")
        pair = values.get("pair")
        row = PoseRow(
            pose_id=int(pose_id),
            q=q,
            spheres=list(spheres),
            set=None if values.get("set") is None else str(values["set"]),
            station=None if values.get("station") is None else str(values["station"]),
            pair=None if pair is None or int(pair) < 0 else int(pair),
            temp_c=None if values.get("temp_c") is None else float(values["temp_c"]),
            t_s=None if values.get("t_s") is None else float(values["t_s"]),
            status=status,
        )
        self._w.write(row)
        seen = sum(s is not None for s in row.spheres)
        self.n_rows += 1
        self.n_spheres += seen
        self.n_complete += int(seen == len(row.spheres))
        self.reasons.update(status_reasons(status))
        if time_s is not None:
            self.times.append(float(time_s))
        return row

    def close(self) -> None:
        self._w.close()

    def __enter__(self) -> "MeasuredRowsWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def path(self) -> Path:
        return self._w.path

    def summary(self, calib: StereoCalibration) -> "MeasureSummary":
        """Counts, reasons and times of the rows written, with the dataset read back to validate it (a failure,
        e.g. too many incomplete rows, is reported in the summary, not raised). Call after closing."""
        err = ""
        try:
            read_dataset(self.folder)
        except DatasetError as exc:
            err = str(exc)
        return MeasureSummary(self.folder, self.n_rows, self.n_complete, self.n_spheres, dict(self.reasons),
                              tuple(self.times), calib, err)


def _read_pair_column(path: Path) -> np.ndarray | None:
    """The optional ``pair`` column of ``joints.csv`` (``twin.dataset.read_joints_csv`` leaves it out)."""
    with open_text(path, ValueError) as f:
        rows = list(csv.DictReader(f))
    if not rows or "pair" not in rows[0]:
        return None
    out = np.full(len(rows), -1, dtype=np.int64)
    for k, r in enumerate(rows):
        t = (r.get("pair") or "").strip()
        if t == "":
            continue
        try:
            out[k] = int(t)
        except ValueError:
            raise ValueError(f"{path}: row {k + 1}, column 'pair': not an integer: {t!r}") from None
    return out


def measure_to_dataset(
    out_dataset: str | os.PathLike,
    joints: Joints,
    image_pairs: Iterable[tuple[np.ndarray | None, np.ndarray | None]],
    calib: StereoCalibration,
    plate: Plate,
    *,
    robot: Any = "irb1200",
    pair: Sequence[int] | None = None,
    bias_correction: bool = True,
    config: MeasureConfig | None = None,
    provenance: str = "",
    on_row: Callable[[int, PoseRow, PairMeasurement | None], None] | None = None,
) -> MeasureSummary:
    """Measure stereo pairs (arrays, in the order of ``joints``) and write the dataset folder.

    ``image_pairs`` yields ``(left, right)`` per row of ``joints``; ``None`` for a missing or unreadable
    image (that row keeps its commanded joints with every sphere empty and the reason in ``status``).
    Rows are streamed to ``poses.csv`` as they are measured, so nothing already measured is lost if the
    run stops; ``dataset.toml`` is written first. The dataset is read back at the end to validate it; a
    validation failure (e.g. too many incomplete rows) is reported in the summary, not raised.
    ``on_row(k, row, measurement)`` is called after each row (progress, recording).
    """
    out = Path(out_dataset)
    n = len(joints.pose_id)
    if pair is not None and len(pair) != n:
        raise ValueError(f"pair: {len(pair)} entries for {n} rows of joints")
    prov = f"{provenance or 'twin measure'}; {instrument_provenance(calib, bias_correction)}"
    write_dataset_toml(out, robot, plate, provenance=prov)
    columns = {c: getattr(joints, c) for c in ("set", "station", "temp_c", "t_s") if getattr(joints, c) is not None}
    if pair is not None:
        columns["pair"] = pair
    it = iter(image_pairs)
    with MeasuredRowsWriter(out, columns=list(columns)) as w:
        for k in range(n):
            try:
                left, right = next(it)
            except StopIteration:
                raise ValueError(f"image_pairs: ran out after {k} pairs for {n} rows of joints") from None
            m = None
            missing = [s for s, im in (("left", left), ("right", right)) if im is None]
            wrong = [s for s, im in (("left", left), ("right", right))
                     if im is not None and np.shape(im)[:2] != (calib.left.height, calib.left.width)]
            if missing or wrong:
                why = "/".join([f"image_missing({s})" for s in missing] + [f"image_size({s})" for s in wrong])
                status, spheres, time_s = format_status([why] * 3), [None, None, None], None
            else:
                m = measure_pair(left, right, calib, plate, bias_correction=bias_correction, config=config)
                status, spheres, time_s = m.status, list(m.centres), m.time_s
            row = w.write(joints.pose_id[k], joints.q[k], spheres, status, time_s=time_s,
                          **{c: v[k] for c, v in columns.items()})
            if on_row is not None:
                on_row(k, row, m)
    return w.summary(calib)


def measure_folder(
    images_dir: str | os.PathLike,
    out_dataset: str | os.PathLike,
    *,
    plate: Plate,
    calib: StereoCalibration | str | os.PathLike | None = None,
    save_calibration: bool = True,
    robot: Any = "irb1200",
    bias_correction: bool = True,
    config: MeasureConfig | None = None,
    provenance: str = "",
    calibration_kwargs: dict | None = None,
    on_row: Callable[[int, PoseRow, PairMeasurement | None], None] | None = None,
) -> MeasureSummary:
    """Measure an image folder (``docs/formats.md``) into a dataset folder.

    The rig is calibrated from ``IMAGES/board/`` unless ``calib`` (a :class:`StereoCalibration` or the path
    of its JSON) is given; the calibration used is saved as ``<out_dataset>/stereo_calibration.json`` so
    that later runs can reuse it. ``plate`` is the nominal plate (it goes to ``dataset.toml``); ``robot`` a
    name ``twin.robots`` knows or an inline table.
    """
    images_dir = Path(images_dir)
    if not images_dir.is_dir():
        raise ValueError(f"images_dir: {images_dir} is not a folder")
    rig = read_rig_toml(images_dir / "rig.toml")
    if calib is None:
        cal = calibrate_folder(images_dir, **(calibration_kwargs or {}))
    elif isinstance(calib, StereoCalibration):
        cal = calib
    else:
        cal = StereoCalibration.load(calib)
    if cal.image_size != (rig.image_width, rig.image_height):
        raise ValueError(
            f"calib: calibrated for {cal.image_size[0]}x{cal.image_size[1]} images, rig.toml says "
            f"{rig.image_width}x{rig.image_height}"
        )
    joints = read_joints_csv(images_dir / "joints.csv")
    pair = _read_pair_column(images_dir / "joints.csv")
    files = pair_files(images_dir)
    out = Path(out_dataset)
    out.mkdir(parents=True, exist_ok=True)
    if save_calibration:
        cal.save(out / CALIBRATION_FILE)

    def images():
        for pid in joints.pose_id:
            f = files.get(int(pid), {})
            yield tuple(read_image(f[s]) if s in f else None for s in ("left", "right"))

    prov = provenance or f"twin measure {images_dir}"
    return measure_to_dataset(
        out, joints, images(), cal, plate, robot=robot, pair=pair, bias_correction=bias_correction,
        config=config, provenance=prov, on_row=on_row,
    )
