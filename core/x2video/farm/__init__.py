"""Render farm: many shots on a Ray cluster (`run_farm`), a long shot split across tasks (frame chunks for tiers 0
and 1, one task per window for diffusion), resumable from a shared output folder,
and Open Job Description templates for the same jobs (`x2video.farm.openjd`). No Qt; Ray is imported only when a
farm runs (`pip install 'x2video-studio[farm]'`). docs/FARM.md has the how-to.

    from x2video.farm import find_jobs, run_farm
    result = run_farm(find_jobs(["shots/"]), "renders/", x2video.RenderSettings(preset="fast"), ModelOptions())
"""
from x2video.farm.jobs import Job, find_jobs
from x2video.farm.runner import FarmResult, run_farm

__all__ = ["FarmResult", "Job", "find_jobs", "run_farm"]
