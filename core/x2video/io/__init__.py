"""Reading and writing shots: folder-per-channel, multi-layer EXR (ours and Blender's), XRGB sets, MP4/PNG/EXR export."""
from x2video.io.load import detect_format, load_shot
from x2video.io.shotdir import ShotWriter, write_shot_folder

__all__ = ["ShotWriter", "detect_format", "load_shot", "write_shot_folder"]
