"""Named colours (the words captions use) and black-body colour temperatures for procedural rooms."""
from __future__ import annotations

import numpy as np

from x2video.channels import srgb_to_linear

#: Caption colour word -> sRGB 8-bit. Spaced apart so the nearest name to a rendered albedo is unambiguous.
NAMED_SRGB: dict[str, tuple[int, int, int]] = {
    "white": (236, 236, 230),
    "light grey": (180, 180, 178),
    "grey": (128, 128, 126),
    "dark grey": (72, 72, 72),
    "black": (28, 28, 30),
    "cream": (236, 222, 186),
    "beige": (200, 178, 140),
    "light brown": (170, 120, 70),
    "brown": (118, 78, 44),
    "dark brown": (66, 42, 26),
    "red": (176, 40, 40),
    "burgundy": (110, 26, 40),
    "orange": (214, 110, 36),
    "yellow": (228, 196, 60),
    "olive": (122, 122, 54),
    "green": (70, 140, 74),
    "dark green": (36, 80, 48),
    "teal": (36, 120, 124),
    "light blue": (150, 190, 222),
    "blue": (56, 96, 176),
    "dark blue": (30, 44, 96),
    "purple": (108, 58, 138),
    "pink": (226, 160, 176),
    # metal tints (captions say "a brass lamp": the colour word is the metal)
    "silver": (206, 208, 214),
    "brass": (206, 164, 80),
    "copper": (190, 110, 80),
}


def linear_rgb(name: str) -> np.ndarray:
    """Linear albedo (3,) of a named colour."""
    if name not in NAMED_SRGB:
        raise KeyError(f"unknown colour name {name!r}")
    return srgb_to_linear(np.array(NAMED_SRGB[name], np.float32) / 255.0)


def nearest_index(albedo_linear: np.ndarray, k: int = 1) -> np.ndarray:
    """Indices into `list(NAMED_SRGB)` of the k names nearest (in sRGB) to linear albedos (..., 3): (..., k)."""
    from x2video.channels import linear_to_srgb

    s = linear_to_srgb(np.asarray(albedo_linear, np.float32)) * 255.0  # (..., 3)
    pal = np.array(list(NAMED_SRGB.values()), np.float32)  # (N, 3)
    d = ((s[..., None, :] - pal) ** 2).sum(-1)  # (..., N)
    return np.argsort(d, axis=-1)[..., :k]


def nearest_names(albedo_linear: np.ndarray, k: int = 1) -> list[str]:
    """The k colour names nearest (in sRGB) to one linear albedo (3,)."""
    names = list(NAMED_SRGB)
    return [names[i] for i in nearest_index(np.asarray(albedo_linear).reshape(3), k)]


def names_in(text: str) -> list[str]:
    """Colour names mentioned in a caption, in order, longest match first ('dark blue' is not also 'blue')."""
    found, words = [], f" {text} "
    for name in sorted(NAMED_SRGB, key=len, reverse=True):
        while f" {name} " in words:
            found.append((words.index(f" {name} "), name))
            words = words.replace(f" {name} ", " " + "#" * len(name) + " ", 1)
    return [n for _, n in sorted(found)]


def kelvin_rgb(kelvin: float) -> np.ndarray:
    """Linear RGB (3,) of a black body at `kelvin`, luminance-normalised to 1 (Tanner Helland's fit)."""
    t = float(np.clip(kelvin, 1000.0, 40000.0)) / 100.0
    if t <= 66:
        r = 255.0
        g = 99.4708025861 * np.log(t) - 161.1195681661
        b = 0.0 if t <= 19 else 138.5177312231 * np.log(t - 10) - 305.0447927307
    else:
        r = 329.698727446 * (t - 60) ** -0.1332047592
        g = 288.1221695283 * (t - 60) ** -0.0755148492
        b = 255.0
    srgb = np.clip(np.array([r, g, b], np.float32), 0, 255) / 255.0
    lin = srgb_to_linear(srgb)
    lum = float(lin @ np.array([0.2126, 0.7152, 0.0722], np.float32))
    return (lin / max(lum, 1e-6)).astype(np.float32)
