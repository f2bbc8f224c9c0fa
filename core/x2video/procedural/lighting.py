"""Lights of a procedural room (point lights, sun, window sky) and the named light moods that choose them."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from x2video.procedural.colors import kelvin_rgb


@dataclass
class PointLight:
    """A light at `position`; at 1 m, facing it, a surface receives irradiance `intensity * colour` (divided-by-pi convention).

    `direction` (unit, optional) gives a cosine emission lobe (window skylight, downlights); `radius`
    softens the inverse-square fall-off near the light: E = I cos / (d^2 + radius^2)."""

    position: np.ndarray
    colour: np.ndarray
    intensity: float
    radius: float = 0.1
    direction: np.ndarray | None = None
    kind: str = "ceiling"  # ceiling | lamp | window


@dataclass
class SunLight:
    """Directional sunlight; `direction` points from the scene towards the sun."""

    direction: np.ndarray
    colour: np.ndarray
    intensity: float


@dataclass
class Lighting:
    """All lights of a shot plus what the windows show and the exposure target of the mood."""

    mood: str
    points: list[PointLight] = field(default_factory=list)
    sun: SunLight | None = None
    #: radiance seen through window glass (not scaled by exposure: daylight clips to white)
    sky: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    #: 98th percentile of max(R, G, B) of the lit image (no emission, no sky) the exposure aims at
    target: float = 0.9
    #: the scale the exposure probe applied to every light (1 until probed)
    exposure: float = 1.0


@dataclass(frozen=True)
class Mood:
    """A named light mood: which sources are on, their colour temperatures, what the window shows, how bright."""

    name: str
    phrase: str  # how the shot caption says it
    ceiling: bool
    lamps: bool
    window_fill: float  # relative strength of skylight through windows (0 = dark outside)
    sun: float  # relative sun strength (0 = none)
    sun_elevation: tuple[float, float]  # degrees
    kelvin_lamps: tuple[float, float]
    kelvin_sky: tuple[float, float]
    sky: tuple[float, float, float]  # window radiance (linear)
    target: float


MOODS: dict[str, Mood] = {m.name: m for m in (
    Mood("warm evening", "in warm evening light", True, True, 0.25, 0.8, (4, 12), (2500, 3000), (2000, 2600), (1.6, 0.9, 0.45), 0.9),
    Mood("cool daylight", "in cool daylight", False, False, 1.0, 0.0, (30, 50), (4000, 4000), (6500, 8000), (2.2, 2.4, 2.6), 0.95),
    Mood("sunny afternoon", "in bright afternoon sunlight", False, False, 0.6, 1.0, (25, 45), (4000, 4000), (5200, 5800), (2.6, 2.6, 2.5), 0.95),
    Mood("overcast", "in soft overcast daylight", False, False, 1.0, 0.0, (30, 50), (4000, 4000), (7000, 9000), (1.8, 1.85, 1.9), 0.85),
    Mood("night", "at night with the lights on", True, True, 0.0, 0.0, (0, 0), (2700, 3500), (9000, 9000), (0.01, 0.015, 0.04), 0.9),
    Mood("dim", "in dim lamp light", False, True, 0.0, 0.0, (0, 0), (2200, 2700), (9000, 9000), (0.01, 0.012, 0.03), 0.55),
    Mood("blue hour", "at dusk with blue light outside and warm lamps", False, True, 0.5, 0.0, (0, 0), (2400, 2800), (11000, 14000), (0.25, 0.35, 0.7), 0.8),
)}


def ceiling_on(mood: Mood, n_lamps: int) -> bool:
    """Ceiling lights are on when the mood says so, or when a lamp-lit mood finds no lamp in the room."""
    return mood.ceiling or (mood.lamps and n_lamps == 0)


def light_points_for(mood: Mood, rng: np.random.Generator, *, ceiling_spots: list[np.ndarray], lamp_bulbs: list[np.ndarray],
                     windows: list[tuple[np.ndarray, np.ndarray, float]]) -> list[PointLight]:
    """Point lights for a mood. `windows`: (centre, inward unit normal, opening area m^2) per window."""
    out: list[PointLight] = []
    if ceiling_on(mood, len(lamp_bulbs)):
        k = rng.uniform(*mood.kelvin_lamps)
        for p in ceiling_spots:
            out.append(PointLight(np.asarray(p, np.float64), kelvin_rgb(k), 1.6, 0.3, np.array([0.0, -1.0, 0.0]), "ceiling"))
    if mood.lamps:
        for p in lamp_bulbs:
            out.append(PointLight(np.asarray(p, np.float64), kelvin_rgb(rng.uniform(*mood.kelvin_lamps)), 0.35, 0.2, None, "lamp"))
    if mood.window_fill > 0:
        k = rng.uniform(*mood.kelvin_sky)
        for c, n, area in windows:
            pos = np.asarray(c, np.float64) + 0.3 * np.asarray(n, np.float64)
            out.append(PointLight(pos, kelvin_rgb(k), 1.2 * mood.window_fill * area, 0.5, np.asarray(n, np.float64), "window"))
    return out


def sun_for(mood: Mood, rng: np.random.Generator, windows: list[tuple[np.ndarray, np.ndarray, float]]) -> SunLight | None:
    """A sun shining in through one of the windows (None when the mood has no sun or the room no window)."""
    if mood.sun <= 0 or not windows:
        return None
    _, n, _ = windows[int(rng.integers(len(windows)))]
    elev = np.radians(rng.uniform(*mood.sun_elevation))
    az = np.arctan2(-n[2], -n[0]) + rng.uniform(-0.6, 0.6)  # outside the window, somewhat to the side
    d = np.array([np.cos(elev) * np.cos(az), np.sin(elev), np.cos(elev) * np.sin(az)])
    kelvin = 2200.0 + 3300.0 * min(1.0, np.degrees(elev) / 40.0)
    return SunLight(d / np.linalg.norm(d), kelvin_rgb(kelvin), 3.0 * mood.sun)


def white_balance(lighting: Lighting, strength: float = 0.7) -> None:
    """Partly neutralise the mean light colour (as a camera's white balance would), in place; keeps luminances."""
    cols = [(p.colour, p.intensity) for p in lighting.points] + ([(lighting.sun.colour, lighting.sun.intensity)] if lighting.sun else [])
    if not cols:
        return
    mean = sum(c * i for c, i in cols) / max(sum(i for _, i in cols), 1e-9)
    gain = (mean / float(mean @ np.array([0.2126, 0.7152, 0.0722]))) ** -strength
    for light in lighting.points + ([lighting.sun] if lighting.sun else []):
        c = light.colour * gain
        light.colour = (c / float(c @ np.array([0.2126, 0.7152, 0.0722]))).astype(np.float32)
