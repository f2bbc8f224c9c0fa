"""Evaluation on held-out rooms (paper Sec. Experimental Results): paper-shaped tables, classical baseline, model card.

`x2video.eval.runner.evaluate` runs the tables, `x2video.eval.report` writes their Markdown,
`x2video.eval.card` composes resources/MODEL_CARD.md, `x2video.eval.contact` writes side-by-side
renders. Only the light config is imported here; the rest loads torch on use.
"""
from x2video.eval.config import TABLES, EvalConfig

__all__ = ["TABLES", "EvalConfig"]
