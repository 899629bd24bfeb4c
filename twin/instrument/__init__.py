"""The instrument: OpenCV stereo calibration, sphere detection, triangulation, plate pose, datasets.

It sees images and the board's nominal geometry only: intrinsics and extrinsics are *estimated* from board
views, never read from the world. Everything is pure (arrays in, results out); ``measure_folder`` adds the
image-folder reader and the dataset writer around it. See ``docs/instrument.md``.
"""

from .calibration import BoardSpec, BoardView, StereoCalibration, ViewReport, calibrate_stereo, detect_board
from .detect import DetectorConfig, SphereImage, detect_spheres
from .folder import (
    MeasuredRowsWriter,
    MeasureSummary,
    RigSpec,
    calibrate_folder,
    measure_folder,
    instrument_provenance,
    measure_to_dataset,
    read_plate_toml,
    read_rig_toml,
)
from .geometry import ConeFit, Ellipse, fit_cone, fit_cone_robust, pixels_to_rays, triangulate_rays
from .measure import MeasureConfig, PairMeasurement, format_status, measure_pair, status_reasons
from .plate import PlateFit, label_by_distances, paper_euler_zyx_deg, paper_frame_from_spheres, plate_pose_from_spheres

__all__ = [
    "BoardSpec",
    "BoardView",
    "StereoCalibration",
    "ViewReport",
    "calibrate_stereo",
    "detect_board",
    "DetectorConfig",
    "SphereImage",
    "detect_spheres",
    "MeasureSummary",
    "MeasuredRowsWriter",
    "instrument_provenance",
    "RigSpec",
    "calibrate_folder",
    "measure_folder",
    "measure_to_dataset",
    "read_plate_toml",
    "read_rig_toml",
    "ConeFit",
    "Ellipse",
    "fit_cone",
    "fit_cone_robust",
    "pixels_to_rays",
    "triangulate_rays",
    "MeasureConfig",
    "PairMeasurement",
    "format_status",
    "status_reasons",
    "measure_pair",
    "PlateFit",
    "label_by_distances",
    "paper_euler_zyx_deg",
    "paper_frame_from_spheres",
    "plate_pose_from_spheres",
]
