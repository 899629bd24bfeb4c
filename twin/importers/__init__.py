"""Importers: files people have -> the dataset seam (``docs/formats.md``). Nothing behind the seam reads a vendor
format: the estimator, the diagnosis and the evaluation see only datasets.

* :mod:`twin.importers.mocap`: a motion-capture campaign in FIGAROH's CSV form and the robot's URDF
  (``twin import CSV --urdf ...``);
* :mod:`twin.importers.columns`: any laser-tracker or motion-capture CSV through a column map (``twin import --map
  MAP.toml``): dialect, joints and units, points or a 6-DOF pose with its Euler convention, time, temperature,
  session, station, set, nominal frames (the map's reader and one CSV read through it:
  :mod:`twin.importers.column_map`).

A foundation-level package: it imports the dataset, kinematics, robots, URDF and transforms modules, never the
world, the estimator or the diagnosis (``tests/test_architecture.py``).
"""

from .columns import (ColumnMap, FileMap, FileSpec, ImportReport, MappedRows, fit_points_on_flange, import_columns,
                      parse_file_argument, read_column_map, read_frame_file, read_mapped_csv)
from .mocap import MocapRows, file_sha256, hand_eye, import_mocap, marker_geometry, read_mocap_csv

__all__ = ["ColumnMap", "FileMap", "FileSpec", "ImportReport", "MappedRows", "fit_points_on_flange", "import_columns",
           "parse_file_argument", "read_column_map", "read_frame_file", "read_mapped_csv", "MocapRows", "file_sha256",
           "hand_eye", "import_mocap", "marker_geometry", "read_mocap_csv"]
