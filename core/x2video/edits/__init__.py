"""Edits: the paper's control inputs and parametric tuning as plain data, applied by a pure function."""
from x2video.edits.masks import Mask
from x2video.edits.model import Edits, Reference
from x2video.edits.ops import OPS, AlbedoHSV, AlbedoSet, AlbedoTint, Exposure, LightTint, MaskOut, Op, ScalarOp, op_from_dict
from x2video.edits.project import PROJECT_SUFFIX, Project, is_project_file, load_project, remove_project, save_project
from x2video.edits.propagate import propagate_mask
from x2video.edits.tuning import NEUTRAL_TUNING

__all__ = [
    "NEUTRAL_TUNING", "OPS", "PROJECT_SUFFIX", "AlbedoHSV", "AlbedoSet", "AlbedoTint", "Edits", "Exposure", "LightTint", "Mask",
    "MaskOut", "Op", "Project", "Reference", "ScalarOp",  "is_project_file", "load_project",
    "op_from_dict", "propagate_mask", "remove_project", "save_project",
]
