"""Material families (roughness/metallic ranges, named colours, procedural albedo patterns) for procedural rooms."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from x2video.procedural.colors import linear_rgb

#: Procedural albedo patterns the shader knows (index = shader pattern id).
PATTERNS = ("flat", "planks", "tiles", "stripes", "noise", "grain", "veins")
#: How a pattern shows up in a caption ("" = not mentioned).
PATTERN_WORDS = {"flat": "", "planks": "plank", "tiles": "tiled", "stripes": "striped", "noise": "", "grain": "", "veins": ""}


@dataclass(frozen=True)
class Family:
    """One material family: caption words, the ranges its samples come from, allowed colours and patterns."""

    name: str
    words: tuple[str, ...]
    roughness: tuple[float, float]
    metallic: tuple[float, float]
    colours: tuple[str, ...]
    patterns: tuple[str, ...] = ("flat",)


FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("fabric", ("fabric", "velvet", "linen", "wool"), (0.8, 1.0), (0.0, 0.0),
           ("white", "light grey", "grey", "dark grey", "cream", "beige", "red", "burgundy", "orange", "yellow",
            "olive", "green", "dark green", "teal", "light blue", "blue", "dark blue", "purple", "pink"),
           ("flat", "flat", "stripes", "noise")),
    Family("leather", ("leather",), (0.35, 0.6), (0.0, 0.0),
           ("black", "brown", "dark brown", "light brown", "burgundy", "white", "cream"), ("flat", "noise")),
    Family("wood", ("wooden", "oak", "walnut", "pine"), (0.3, 0.7), (0.0, 0.0),
           ("light brown", "brown", "dark brown", "beige"), ("grain",)),
    Family("painted", ("painted",), (0.5, 0.9), (0.0, 0.0),
           ("white", "light grey", "grey", "cream", "beige", "light blue", "green", "yellow", "pink", "teal",
            "dark blue", "black"), ("flat", "flat", "noise")),
    Family("plastic", ("plastic",), (0.2, 0.5), (0.0, 0.0),
           ("white", "black", "red", "yellow", "blue", "green", "orange", "grey"), ("flat",)),
    Family("ceramic", ("ceramic", "porcelain"), (0.05, 0.25), (0.0, 0.0),
           ("white", "cream", "light blue", "teal", "grey", "dark green", "black"), ("flat", "flat", "noise")),
    Family("metal", ("metal", "steel", "chrome"), (0.08, 0.45), (0.9, 1.0),
           ("silver", "brass", "copper", "black"), ("flat", "noise")),
    Family("stone", ("marble", "granite", "polished stone"), (0.04, 0.2), (0.0, 0.0),
           ("white", "light grey", "grey", "black", "beige"), ("veins", "noise")),
    Family("canvas", ("canvas",), (0.75, 0.95), (0.0, 0.0),
           ("red", "orange", "yellow", "teal", "blue", "dark blue", "green", "pink", "purple", "light blue", "cream"), ("flat", "noise", "stripes")),
    Family("foliage", ("leafy",), (0.55, 0.85), (0.0, 0.0), ("green", "dark green", "olive"), ("noise",)),
    Family("concrete", ("concrete",), (0.7, 0.95), (0.0, 0.0), ("grey", "light grey", "dark grey"), ("noise",)),
)}


@dataclass
class Material:
    """One surface material: what the shader needs (linear albedo, pattern, roughness, metallic, emission) and the caption words."""

    family: str
    word: str
    colour: str
    albedo: np.ndarray  # (3,) linear
    roughness: float
    metallic: float
    pattern: str = "flat"
    #: pattern period in metres (plank width, tile size, stripe width, noise feature size)
    scale: float = 0.2
    #: relative albedo variation of the pattern (mean stays at `albedo`)
    contrast: float = 0.1
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))
    #: True for the sky seen through windows: albedo = irradiance = 0 there, rgb = emission
    sky: bool = False

    def describe(self) -> str:
        """Caption fragment: colour + pattern + material word, e.g. 'dark blue striped velvet', 'brass'."""
        colour = "" if self.word == self.colour else self.colour  # metals: "brass", not "brass brass"
        parts = [colour, PATTERN_WORDS.get(self.pattern, ""), self.word]
        return " ".join(p for p in parts if p)


def sample_material(rng: np.random.Generator, family: str, colours: tuple[str, ...] | None = None,
                    pattern: str | None = None) -> Material:
    """Draw a material of `family`; `colours` narrows the colour choice (style palettes), `pattern` forces one."""
    fam = FAMILIES[family]
    allowed = [c for c in fam.colours if colours is None or c in colours] or list(fam.colours)
    colour = str(rng.choice(allowed))
    word = str(rng.choice(fam.words))
    if family == "metal":
        word = {"brass": "brass", "copper": "copper", "silver": str(rng.choice(["steel", "chrome", "metal"]))}.get(colour, "metal")
    pat = pattern or str(rng.choice(fam.patterns))
    scale = {"planks": rng.uniform(0.12, 0.22), "tiles": rng.uniform(0.2, 0.6), "stripes": rng.uniform(0.04, 0.12),
             "noise": rng.uniform(0.05, 0.3), "grain": rng.uniform(0.02, 0.05), "veins": rng.uniform(0.2, 0.5)}.get(pat, 0.2)
    contrast = {"planks": 0.1, "tiles": 0.08, "stripes": 0.15, "noise": 0.07, "grain": 0.08, "veins": 0.1}.get(pat, 0.0)
    m = Material(family=family, word=word, colour=colour, albedo=linear_rgb(colour),
                 roughness=float(rng.uniform(*fam.roughness)), metallic=float(rng.uniform(*fam.metallic)),
                 pattern=pat, scale=float(scale), contrast=float(contrast))
    return m


def emissive(colour: np.ndarray, strength: float, *, word: str = "glowing", name: str = "white") -> Material:
    """A light-emitting surface (lamp shade glow, bulb): white albedo, rough, emits `colour * strength`."""
    return Material(family="emissive", word=word, colour=name, albedo=linear_rgb("white"), roughness=1.0, metallic=0.0,
                    emission=(np.asarray(colour, np.float32) * strength).astype(np.float32))


def sky(radiance: np.ndarray) -> Material:
    """The view through a window: no albedo, no irradiance, rgb = `radiance` (daylight clips to white)."""
    return Material(family="sky", word="window", colour="white", albedo=np.zeros(3, np.float32), roughness=1.0,
                    metallic=0.0, emission=np.asarray(radiance, np.float32), sky=True)
