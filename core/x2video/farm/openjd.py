"""Open Job Description job templates (specification `jobtemplate-2023-09`) for farm jobs, one per shot: the
same render as `x2video farm`, as one step running `x2video render ...`, for schedulers that read OpenJD (AWS
Deadline Cloud; `openjd run NAME.template.json -p file://NAME.params.json` runs one on this machine). The flags come
from the settings dataclasses (`x2video.fields.to_flags`), so a template renders what `x2video farm` with the
same flags renders. The shot and output paths are job parameters without defaults (OpenJD wants a PATH default
relative to the template's folder, and shots live elsewhere): `NAME.params.json` beside the template holds them.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from x2video.farm import state
from x2video.farm.jobs import Job
from x2video.fields import to_flags
from x2video.io.atomic import write_json_atomic

if TYPE_CHECKING:
    from x2video.render.settings import RenderSettings
    from x2video.weights import ModelOptions

SPECIFICATION = "jobtemplate-2023-09"


def job_template(job: Job, output: Path, settings: RenderSettings, options: ModelOptions, fps: float | None = None) -> dict[str, Any]:
    """The job template (a dict, JSON-ready) that renders `job` to `output` with `settings` and `options`
    (`x2video.RenderSettings`, `x2video.weights.ModelOptions`): parameters for the shot or project and the output
    (`job_parameters` gives their values) and the `x2video` command on the worker, and one step 'Render'."""
    from x2video.render.settings import RenderSettings
    from x2video.weights import ModelOptions

    source = "Project" if job.kind == "project" else "Shot"
    mp4 = output.suffix.lower() == ".mp4"
    params = [
        {"name": source, "type": "PATH", "objectType": "FILE" if job.kind == "project" or job.source.is_file() else "DIRECTORY",
         "dataFlow": "IN", "description": f"the {source.lower()} to render"},
        {"name": "Output", "type": "PATH", "objectType": "FILE" if mp4 else "DIRECTORY", "dataFlow": "OUT",
         "description": "the render: an MP4 file or a folder of EXR frames (written atomically)"},
        {"name": "X2Video", "type": "STRING", "default": "x2video", "minLength": 1,
         "description": "the x2video command on the worker (a path, or a name on its PATH)"},
    ]
    args = ["render", *(["--project"] if job.kind == "project" else []), "{{Param.%s}}" % source, "--out", "{{Param.Output}}"]
    if fps is not None:
        args += ["--fps", repr(float(fps))]
    args += to_flags(RenderSettings, settings) + to_flags(ModelOptions, options)
    return {
        "specificationVersion": SPECIFICATION,
        "name": f"x2video render {job.name}",
        "description": f"X2Video Studio: render {job.source.name} ({job.kind}) with `x2video render`; written by `x2video farm --openjd`.",
        "parameterDefinitions": params,
        "steps": [{
            "name": "Render",
            "description": "one task: the whole shot (`x2video farm` on Ray splits shots into chunks or windows; this step does not)",
            "script": {"actions": {"onRun": {"command": "{{Param.X2Video}}", "args": args}}},
        }],
    }


def job_parameters(job: Job, output: Path) -> dict[str, str]:
    """Values of the template's path parameters for `job` (`openjd run -p file://NAME.params.json`)."""
    return {"Project" if job.kind == "project" else "Shot": str(job.source), "Output": str(output)}


def write_templates(jobs: list[Job], folder: str | Path, out: str | Path, settings: RenderSettings, options: ModelOptions, fmt: state.OutputFormat = "exr",
                    fps: float | None = None) -> list[Path]:
    """Write `folder/NAME.template.json` and its parameter values `folder/NAME.params.json` for each job (rendering into
    the farm output folder `out`); returns the templates' paths."""
    folder, out = Path(folder), Path(out).resolve()
    paths = []
    for job in jobs:
        path = folder / f"{job.name}.template.json"
        output = state.output_path(out, job.name, fmt)
        write_json_atomic(path, job_template(job, output, settings, options, fps), indent=2)
        write_json_atomic(folder / f"{job.name}.params.json", job_parameters(job, output), indent=2)
        paths.append(path)
    return paths
