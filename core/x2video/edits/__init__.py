"""Edits: the paper's control inputs and parametric tuning as plain data, applied by a pure function."""
from x2video.edits.apply import apply_edits, fit_image, resolve_reference
from x2video.edits.masks import Mask
from x2video.edits.model import Edits, Reference
from x2video.edits.ops import OPS, AlbedoHSV, AlbedoSet, AlbedoTint, Exposure, LightTint, MaskOut, Op, ScalarOp, op_from_dict
from x2video.edits.project import Project, load_project, save_project
from x2video.edits.propagate import propagate_mask

__all__ = [
    "OPS", "AlbedoHSV", "AlbedoSet", "AlbedoTint", "Edits", "Exposure", "LightTint", "Mask", "MaskOut", "Op",
    "Project", "Reference", "ScalarOp", "apply_edits", "fit_image", "load_project", "op_from_dict",
    "propagate_mask", "resolve_reference", "save_project",
]
