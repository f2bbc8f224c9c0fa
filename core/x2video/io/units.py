"""Units in = units out: the one place that turns rendered frames (in the model's exposure) into what is written.

Loaders may normalise a shot's irradiance exposure once per shot (`ShotInfo.irradiance_scale`:
loaded irradiance = file irradiance x scale, docs/ARCHITECTURE.md "Channel convention"). The model renders in that normalised
exposure, so a rendered frame is ``scale x`` the radiance the input's units would give. Every
writer of rendered frames (the CLI's `FrameSink`, the editor's exporter) goes through
`OutputUnits`:

- linear EXR: ``rgb / irradiance_scale``, the input's radiometric units (a Blender shot's EXR
  comes back in Blender's units), with the scale recorded in the header;
- MP4: scene-referred radiance times ``2 ** stops``, then `x2video.channels.tonemap`; ``stops``
  is the user's exposure, or "auto" = ``log2(irradiance_scale)``, which shows exactly what the
  model saw (the shot's own normalisation).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from x2video.channels import tonemap

AUTO = "auto"


def parse_exposure(value: Any) -> float | str:
    """"auto" or a finite number of stops (from a CLI string, a settings value or a project file)."""
    if value is None or (isinstance(value, str) and value.strip().lower() == AUTO):
        return AUTO
    try:
        stops = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"exposure: expected 'auto' or a number of stops, got {value!r}") from None
    if not math.isfinite(stops):
        raise ValueError(f"exposure: {value!r} is not a finite number of stops")
    return stops


@dataclass(frozen=True)
class OutputUnits:
    """How rendered frames leave: see the module docstring.

    irradiance_scale: what the loader multiplied the shot's irradiance by (1.0: none).
    exposure: MP4 exposure in stops on scene-referred radiance, or "auto" (= log2(irradiance_scale)).
    """

    irradiance_scale: float = 1.0
    exposure: float | str = AUTO

    def __post_init__(self) -> None:
        if not (math.isfinite(self.irradiance_scale) and self.irradiance_scale > 0):
            raise ValueError(f"irradiance_scale must be a positive number, got {self.irradiance_scale!r}")
        object.__setattr__(self, "exposure", parse_exposure(self.exposure))

    @classmethod
    def for_shot(cls, shot: Any, exposure: Any = AUTO) -> OutputUnits:
        """The units of renders of `shot` (a `Shot` or a `ShotInfo`)."""
        info = getattr(shot, "info", shot)
        return cls(float(getattr(info, "irradiance_scale", 1.0) or 1.0), exposure)

    @property
    def stops(self) -> float:
        """The MP4 exposure in stops on scene-referred radiance."""
        return math.log2(self.irradiance_scale) if self.exposure == AUTO else float(self.exposure)

    def scene(self, rgb: np.ndarray) -> np.ndarray:
        """Rendered linear RGB (model exposure) -> the input's radiometric units, float32."""
        if self.irradiance_scale != 1.0 and np.asarray(rgb).dtype == np.float64:
            # the base's frames (x2video.base.stage: the shot's float32 rgb x scale, in float64): divided as they were
            # multiplied, they come back bit for bit
            return (np.asarray(rgb) / self.irradiance_scale).astype(np.float32)
        a = np.asarray(rgb, dtype=np.float32)
        return a if self.irradiance_scale == 1.0 else (a / np.float32(self.irradiance_scale)).astype(np.float32)

    def display(self, rgb: np.ndarray) -> np.ndarray:
        """Rendered linear RGB (model exposure) -> sRGB in [0, 1] for an MP4 at this exposure."""
        gain = np.float32(2.0 ** self.stops / self.irradiance_scale)
        return tonemap(np.asarray(rgb, dtype=np.float32) * gain)

    def exr_attributes(self) -> dict[str, Any]:
        """Header attributes of a written EXR frame that say which units it is in."""
        return {"x2video:units": "input", "x2video:irradiance_scale": float(self.irradiance_scale)}

    def describe(self) -> str:
        """One line for the log: what the EXR and MP4 outputs are in."""
        how = (f"auto = the shot's irradiance normalisation x{self.irradiance_scale:.4g}" if self.exposure == AUTO
               else "set by the user")
        return (f"EXR in the input's units (rendered radiance / {self.irradiance_scale:.4g}); "
                f"MP4 exposure {self.stops:+.2f} stops ({how})")
