"""The methods of the grid: the peers (when their extra is installed) and ours."""

from __future__ import annotations

from . import figaroh_adapter, pybotics_adapter, robotkinecal_adapter
from .harness import Method

__all__ = ["peer_methods", "unavailable_peers"]


def peer_methods() -> list[Method]:
    """Every peer variant whose library is installed, with its stated settings."""
    out: list[Method] = []
    if figaroh_adapter.available():
        for variant, data in (("pose", "pose"), ("pose-example-weights", "pose"), ("position", "position")):
            out.append(
                Method(
                    name=f"FIGAROH ({variant})",
                    family="peer",
                    data=data,
                    run=lambda pb, sp, v=variant: figaroh_adapter.calibrate(
                        pb.nominal, sp.q_cal, sp.tool2meas_cal, sp.q_val, sp.noise.position, sp.noise.orientation,
                        variant=v,
                    ),
                    settings=figaroh_adapter.SETTINGS,
                    data_used=variant,
                )
            )
    if pybotics_adapter.available():
        out.append(
            Method(
                name="pybotics (position)",
                family="peer",
                data="position",
                run=lambda pb, sp: pybotics_adapter.calibrate(pb.nominal, sp.q_cal, sp.tool2meas_cal, sp.q_val),
                settings=pybotics_adapter.SETTINGS,
                data_used="position",
            )
        )
    if robotkinecal_adapter.available():
        for variant in ("pose", "position"):
            out.append(
                Method(
                    name=f"robotkinecal ({variant})",
                    family="peer",
                    data=variant,
                    run=lambda pb, sp, v=variant: robotkinecal_adapter.calibrate(
                        pb.nominal, sp.q_cal, sp.tool2meas_cal, sp.q_val, variant=v
                    ),
                    settings=robotkinecal_adapter.SETTINGS,
                    data_used=variant,
                )
            )
    return out


def unavailable_peers() -> list[str]:
    """Names of the peers whose library is missing (the benchmark says so instead of skipping silently)."""
    missing = []
    for mod in (figaroh_adapter, pybotics_adapter, robotkinecal_adapter):
        if not mod.available():
            missing.append(mod.NAME)
    return missing
