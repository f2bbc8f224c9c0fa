"""The X2Video model (paper Sec. Methodology) on diffusers: configs, UNet conversion, attention processors, VAE/text, checkpoints.

Submodules are imported explicitly (`x2video.model.pipeline.X2VideoModel`, ...) so that
`x2video.model.api` stays importable without loading diffusers.
"""
