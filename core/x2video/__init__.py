"""X2Video: intrinsic channels to photorealistic video with a video diffusion model (no Qt here)."""

__version__ = "0.1.0"
