"""The speed-accuracy chart: seconds per frame (log) against PSNR and TC on path-traced test rooms, for every way
of making the picture: the formula, tier 1, the diffusion sampler's step counts and schemes, and Cycles itself.

    python -m bench.pareto --data DATA/pt160,DATA/pt320 --sizes 160x112,320x224 [--rooms 2 --frames 4] (or --rooms 2,1: per size)
        [--methods formula,residual,ddim-20,...,cycles-64] [--reference-samples 128] [--threads 2]
    python -m bench.pareto ...the same data, sizes, rooms, frames... --methods residual --merge docs/pareto.json
    python -m bench.pareto --data DATA/pt160 --sizes 160x112 --rooms 1 --frames 8 --methods lcm-2,lcm-2-seq \
        --merge docs/pareto.json --section "long shot"

`--merge` reruns some methods into an existing result (new weights, a quieter machine): their rows replace the rows
of the same method and size, the others stay, and every row names the run that measured it (`runs`: command, commit,
date, load, weights digest), so a chart of several runs says so. It is refused unless the run measures the same
thing: the same data folders, shots and frames (names and a digest of the channels), the same ground truth (kind,
samples, seed; the reference render's digest, else the deterministic formula row re-scored against the kept one).
`--section NAME` keeps rows of other shots or frames (recursive against sequential sampling needs a shot longer than
a window) in a section of their own, drawn below the main panels; the editor reads the main rows.

For each size, the first `--rooms` finished shots of that size among the `--data` folders (DATA/<split>/<shot>/,
from `x2video dataset make --renderer cycles`) and their first `--frames` frames. Methods:

    formula          tier 0: albedo x irradiance (RenderSettings.quality 'formula')
    residual         tier 1: one pass of the shipped tier-1 net (quality 'residual')
    ddim-S, lcm-S    tier 2: the video diffusion sampler with S steps, Recursive Sampling
    ddim-S-seq, ...  the same with sequential sampling (skipped, and said so, where the two plans are the same
                     windows: shots no longer than one window)
    cycles-S         Cycles at S samples per pixel, OpenImageDenoise'd: the room rebuilt from its seed
                     (`x2video.cycles.shot.beauty_scene`: same scene, cameras, light gain) and only the picture
                     rendered, as a Blender user would, in a Blender process of its own, timed in this run

Ground truth: with `--reference-samples R` (default 128) the bench renders its own reference of the same frames
with Cycles at R samples, denoised, with another noise seed than the rows (the data sets' frames were rendered
at fewer samples, often 32, with the rows' seed: a Cycles row at 64 samples is not to be scored against them);
with 0 it scores against the data set's frames (N samples, OpenImageDenoise'd) and says so. Every row is also
scored against the data set's frames (`psnr_dataset`). Scoring is `bench.ptscore` (as bench.pathtraced):
PSNR/SSIM on display images in the shot's units, TC = warping error over the ground truth's (DIS flow).

Seconds per frame: wall time of the render of the shot's frames over their count; the model loaded, one
untimed warm-up per size, each method with a fresh conditioning cache (it pays its own encoding); Cycles:
the render call per frame (scene sync, path tracing, denoising, writing the EXR), the scene built beforehand.

Writes docs/pareto.json (`--out`), docs/pareto.png (two panels, matplotlib) and bench/results/pareto/pareto.md.
The editor's speed-vs-accuracy chart reads docs/pareto.json and marks the setting of the current render.

The package: `methods` (the rows), `data` (shots, digests, Cycles' renders), `measure` (the bench and its summary),
`merge` (`--merge`, `--section`), `chart` (the PNG), `report` (the Markdown), `cli` (the command).
"""
